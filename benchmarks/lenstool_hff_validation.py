"""Source-plane scatter of published Lenstool models: SMACS0723 and the four HFF CATS models.

For every system of a model's multiple-image catalogue with a known or
fitted redshift, the images are traced back to the source plane with the
model (multi-plane where the model has several planes); the scatter of a
system is the rms distance of its traced images to their mean. The
image-plane rms is that scatter mapped back through each image's local
Jacobian (``|A^-1 (beta_i - mean beta)|``, rms over the system's images), the
usual cheap proxy of Lenstool's image-plane chi2 (``sigposArcsec``-free).

Run on demand (needs ``../shared/data``)::

    python benchmarks/lenstool_hff_validation.py [--systems] [--variants]

``--systems`` prints the per-system numbers, ``--variants`` the scatter under
alternative conventions (the convention check: a wrong one gives arcsec).
"""

import argparse
import warnings
from pathlib import Path

import numpy as np

from lensdual.parametric import LenstoolLensModel, read_lenstool, read_lenstool_images

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
MODELS = {
    "SMACS0723": ("smacs0723_mahler2022", "best.par", "arcs.dat"),
    "Abell 2744": ("hff_cats_lenstool/abell2744", "best.par", "img_mul_constraints.cat"),
    "Abell S1063": ("hff_cats_lenstool/abells1063_gold", "best.par", "mul_gold.cat"),
    "Abell 370": ("hff_cats_lenstool/abell370", "best.par", "mul_a370_specMosaic.cat"),
    "MACS J1149": ("hff_cats_lenstool/macs1149_v4", "best.par", "imawcs_spiral_secured.mul"),
}


def load(name):
    folder, par, cat = MODELS[name]
    path = DATA / folder
    if not (path / par).is_file() or not (path / cat).is_file():
        return None
    model = read_lenstool(path / par)
    return model, read_lenstool_images(path / cat, reference=model)


def system_scatter(model, images, lens_model=None):
    """Per-system (n_images, z, z from, source rms, image-plane rms), arcsec.

    ``lens_model(z)`` gives the deflection model (default ``model.lens_model``).
    """
    lens_model = lens_model or model.lens_model
    out = {}
    for system in dict.fromkeys(images["system"]):
        sel = images[images["system"] == system]
        if len(sel) < 2:
            continue
        z = float(sel["z_model"][0])
        if not np.isfinite(z):
            continue
        lm = lens_model(z)
        x, y = sel["x"].value, sel["y"].value
        bx, by = lm.ray_shooting(x, y)
        dx, dy = bx - bx.mean(), by - by.mean()
        src = float(np.sqrt(np.mean(dx**2 + dy**2)))
        fxx, fxy, fyx, fyy = lm.hessian(x, y)
        a11, a12, a21, a22 = 1 - fxx, -fxy, -fyx, 1 - fyy
        det = a11 * a22 - a12 * a21
        ix = (a22 * dx - a12 * dy) / det
        iy = (-a21 * dx + a11 * dy) / det
        img = float(np.sqrt(np.mean(ix**2 + iy**2)))
        known = np.isfinite(sel["z"][0])
        out[str(system)] = (len(sel), z, "spec" if known else "fit", src, img)
    return out


def summary(scatter):
    src = np.array([v[3] for v in scatter.values()])
    img = np.array([v[4] for v in scatter.values()])
    n_img = sum(v[0] for v in scatter.values())
    worst = max(scatter, key=lambda k: scatter[k][3])
    return {"systems": len(src), "images": n_img, "median": np.median(src),
            "mean": src.mean(), "worst": src.max(), "worst_system": worst,
            "img_rms": np.sqrt(np.sum(img**2 * [v[0] for v in scatter.values()]) / n_img),
            "img_median": np.median(img)}


def rst_table(header, rows):
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=True)]
    line = "  ".join("=" * w for w in widths)
    out = [line, "  ".join(str(h).ljust(w) for h, w in zip(header, widths, strict=True)), line]
    out += ["  ".join(str(x).ljust(w) for x, w in zip(r, widths, strict=True)) for r in rows]
    out.append(line)
    return "\n".join(out)


def _single_plane_sum(model):
    """Lenstool 6.8's treatment of several z_lens: one plane, each potential scaled by
    its own D_ls / D_s (e_grad2.c), no recursion."""
    def make(z):
        return LenstoolLensModel(model.kernel_parameters(z, profile=81),
                                 model.kernel_parameters(z, profile=12),
                                 shear=model.kernel_parameters(z, profile=14))
    return make


def _drop_planes(model):
    """Only the main plane's potentials."""
    def make(z):
        zp = model.z_lens
        return LenstoolLensModel(model.kernel_parameters(z, profile=81, z_plane=zp),
                                 model.kernel_parameters(z, profile=12, z_plane=zp),
                                 shear=model.kernel_parameters(z, profile=14, z_plane=zp))
    return make


def _shear_variant(model, how):
    def make(z):
        shear = model.kernel_parameters(z, profile=14)
        if how == "none":
            shear = None
        elif how == "unscaled":
            shear = model.kernel_parameters(None, profile=14)
        elif how == "rotated":
            shear[:, 2] += np.pi / 2
        elif how == "clockwise":
            shear[:, 2] = -shear[:, 2]
        return LenstoolLensModel(model.kernel_parameters(z, profile=81),
                                 model.kernel_parameters(z, profile=12), shear=shear)
    return make


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", action="store_true", help="per-system numbers")
    parser.add_argument("--variants", action="store_true", help="alternative conventions")
    args = parser.parse_args(argv)
    rows = []
    loaded = {}
    for name in MODELS:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            got = load(name)
        if got is None:
            print(f"{name}: data not found under {DATA}")
            continue
        loaded[name] = got
        model, images = got
        sc = system_scatter(model, images)
        s = summary(sc)
        chi2 = model.meta.get("chi2", np.nan)
        dof = model.meta.get("dof", 0)
        rows.append((name, len(model), ", ".join(f"{z:g}" for z in model.z_planes),
                     f"{s['systems']} ({s['images']})", f"{s['median']:.3f}",
                     f"{s['mean']:.3f}", f"{s['worst']:.3f} ({s['worst_system']})",
                     f"{s['img_median']:.3f}", f"{s['img_rms']:.3f}", f"{chi2:.1f} / {dof}"))
        if args.systems:
            print(name)
            print(rst_table(("system", "images", "z", "z from", "source rms", "image rms"),
                            [(k, v[0], f"{v[1]:.4f}", v[2], f"{v[3]:.3f}", f"{v[4]:.3f}")
                             for k, v in sc.items()]))
    print(rst_table(("model", "potentials", "z planes", "systems (images)", "median",
                     "mean", "worst (system)", "image median", "image rms",
                     "Lenstool chi2 / dof"), rows))
    if not args.variants:
        return
    rows = []
    variants = []
    if "Abell 370" in loaded:
        m, im = loaded["Abell 370"]
        variants += [("Abell 370", "multi-plane (lensdual)", m, im, None),
                     ("Abell 370", "one plane, per-plane D_ls/D_s", m, im, _single_plane_sum(m)),
                     ("Abell 370", "z = 1.05 potentials dropped", m, im, _drop_planes(m))]
    if "Abell S1063" in loaded:
        m, im = loaded["Abell S1063"]
        variants += [("Abell S1063", "shear as Lenstool (scaled)", m, im, None)]
        for how, label in (("unscaled", "gamma not scaled by D_ls/D_s"),
                           ("rotated", "angle_pos + 90 deg"),
                           ("clockwise", "angle_pos clockwise"),
                           ("none", "no shear")):
            variants.append(("Abell S1063", label, m, im, _shear_variant(m, how)))
    for name, label, m, im, make in variants:
        s = summary(system_scatter(m, im, make))
        rows.append((name, label, f"{s['median']:.3f}", f"{s['worst']:.3f}",
                     f"{s['img_rms']:.3f}"))
    print()
    print(rst_table(("model", "variant", "median", "worst", "image rms"), rows))


if __name__ == "__main__":
    main()
