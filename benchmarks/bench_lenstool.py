"""Speed of the dPIE kernels on the SMACS0723 Lenstool model against lenstronomy.

Run on demand (not part of the test suite)::

    python benchmarks/bench_lenstool.py [--grid 1000] [--half-width 60] [--quick]
                                      [--output FILE]

The 149 dPIE potentials of ``best.par`` (Mahler et al. 2023) are evaluated
(deflection and Hessian) on a ``grid x grid`` square of the model frame, in
one process, by

* ``lensdual``: :class:`~lensdual.parametric.DPIELensModel` (``alpha`` then
  ``hessian``, as lenstronomy is called, and ``alpha_hessian`` in one pass),
  on one thread and on all cores (the kernels release the GIL);
* lenstronomy doing equal work: the same model as 298 ``NIE`` profiles (each
  dPIE is the difference of two cored isothermal ellipses, so this is exactly
  the same lens; the deflections are compared), 149
  ``PJAFFE_ELLIPSE_POTENTIAL`` (the dPIE with the ellipticity in the
  potential) and 149 circular ``PJAFFE``.

lenstronomy's ``NIE`` and ``PJAFFE_ELLIPSE_POTENTIAL`` Hessians are finite
differences of the deflection (step 1e-10 and 1e-5 arcsec), so only the
deflections are compared for accuracy.

Then one elliptical NFW (Lenstool's profile 12, ellipticity in the potential)
on the same grid: the lensdual NFW kernel (``LenstoolLensModel(nfw=...)``)
against lenstronomy's ``NFW_ELLIPSE_POTENTIAL``, the same profile (its
Hessian: forward differences of the deflection).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from _output import Record, add_output_argument

HERE = Path(__file__).resolve().parent
DATA = HERE.parents[1] / "shared" / "data" / "smacs0723_mahler2022"


def best_of(func, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = func()
        times.append(time.perf_counter() - start)
    return min(times), result


def lenstronomy_nie(params):
    """The dPIEs as pairs of lenstronomy NIE (core term minus cut term)."""
    profiles, kwargs = [], []
    for xc, yc, theta, eps, core, cut, b0 in params:
        q = (1 - eps) / (1 + eps)
        b = b0 * cut / (cut - core) * (1 - eps)  # Keeton's b of each term
        e1, e2 = eps * np.cos(2 * theta), eps * np.sin(2 * theta)
        for sign, radius in ((1.0, core), (-1.0, cut)):
            profiles.append("NIE")
            kwargs.append(dict(theta_E=sign * b / np.sqrt(q), e1=e1, e2=e2,
                               s_scale=(1 + eps) * radius * np.sqrt(q), center_x=xc,
                               center_y=yc))
    return profiles, kwargs


def lenstronomy_pjaffe(params, elliptical):
    profiles, kwargs = [], []
    for xc, yc, theta, eps, core, cut, b0 in params:
        kw = dict(sigma0=b0 / (2 * core), Ra=core, Rs=cut, center_x=xc, center_y=yc)
        if elliptical:
            kw.update(e1=eps * np.cos(2 * theta), e2=eps * np.sin(2 * theta))
        profiles.append("PJAFFE_ELLIPSE_POTENTIAL" if elliptical else "PJAFFE")
        kwargs.append(kw)
    return profiles, kwargs


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=1000, help="grid points per side")
    parser.add_argument("--half-width", type=float, default=60.0, help="arcsec")
    parser.add_argument("--z-source", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=3, help="best of, lensdual only")
    parser.add_argument("--quick", action="store_true",
                        help="lenstronomy on a 1/10 subset of the grid, scaled up")
    add_output_argument(parser)
    args = parser.parse_args()
    rec = Record()
    if not (DATA / "best.par").is_file():
        print(f"SMACS0723 model not found in {DATA}; nothing to do")
        return 0

    from lenstronomy.LensModel.lens_model import LensModel

    from lensdual.parametric import read_lenstool

    model = read_lenstool(DATA / "best.par")
    n = args.grid
    side = np.linspace(-args.half_width, args.half_width, n)
    xx, yy = np.meshgrid(side, side)
    x, y = xx.ravel(), yy.ravel()
    params = model.kernel_parameters(args.z_source, profile=81)
    rec.say(f"{model}\nz_source = {args.z_source}, grid {n} x {n} = {x.size} points over "
            f"+-{args.half_width} arcsec, {len(params)} potentials, {os.cpu_count()} cores")

    lm1 = model.lens_model(args.z_source)
    lmn = model.lens_model(args.z_source, n_threads=os.cpu_count() or 1)
    lm1.alpha_hessian(x[:10], y[:10])  # compile (or load the Numba cache)
    lm1.alpha(x[:10], y[:10])
    lm1.hessian(x[:10], y[:10])

    rows = []
    t_sep, ours = best_of(lambda: (lm1.alpha(x, y), lm1.hessian(x, y)), args.repeat)
    rows.append(("lensdual alpha + hessian, 1 thread", t_sep))
    t_one, _ = best_of(lambda: lm1.alpha_hessian(x, y), args.repeat)
    rows.append(("lensdual alpha_hessian (one pass), 1 thread", t_one))
    t_all, _ = best_of(lambda: lmn.alpha_hessian(x, y), args.repeat)
    rows.append((f"lensdual alpha_hessian, {lmn.n_threads} threads", t_all))
    (ax, ay), _ = ours

    sub = slice(None, None, 10) if args.quick else slice(None)
    scale = 10.0 if args.quick else 1.0
    for label, (profiles, kwargs) in (
        ("lenstronomy 298 NIE (same model)", lenstronomy_nie(params)),
        ("lenstronomy 149 PJAFFE_ELLIPSE_POTENTIAL", lenstronomy_pjaffe(params, True)),
        ("lenstronomy 149 PJAFFE (circular)", lenstronomy_pjaffe(params, False)),
    ):
        lm = LensModel(profiles)
        lm.alpha(x[:10], y[:10], kwargs)
        start = time.perf_counter()
        lax, lay = lm.alpha(x[sub], y[sub], kwargs)
        lm.hessian(x[sub], y[sub], kwargs)
        rows.append((label, (time.perf_counter() - start) * scale))
        if "NIE" in label:
            diff = max(np.abs(lax - ax[sub]).max(), np.abs(lay - ay[sub]).max())
            rec.say(f"max |alpha_lensdual - alpha_NIE| = {diff:.2e} arcsec "
                    f"(max |alpha| = {np.hypot(ax, ay).max():.1f} arcsec)")

    rec.say()
    rec.say(f"{'':48s} {'time [s]':>9s}  {'lenstronomy / lensdual':>22s}")
    rec.say(f"{'':48s} {'':9s}  {'1 thread':>10s} {'all cores':>10s}")
    for label, t in rows:
        if label.startswith("lenstronomy"):
            rec.say(f"{label:48s} {t:9.2f}  {t / t_sep:9.1f}x {t / t_all:9.1f}x")
        else:
            rec.say(f"{label:48s} {t:9.2f}")
    if args.quick:
        rec.say("(lenstronomy timed on every 10th point and scaled by 10)")

    # one elliptical NFW: r_s = 30 arcsec, b0 = 20 arcsec, epsilon = 0.2 (potential)
    from lensdual.parametric import LenstoolLensModel

    eps, theta, rs, b0 = 0.2, 0.5, 30.0, 20.0
    nfw = LenstoolLensModel(nfw=[[0.0, 0.0, theta, eps, rs, b0]])
    nfw.alpha_hessian(x[:10], y[:10])
    t_nfw, (nax, nay, *_) = best_of(lambda: nfw.alpha_hessian(x, y), args.repeat)
    q = np.sqrt((1 - eps) / (1 + eps))
    c = (1 - q) / (1 + q)
    kw = [dict(Rs=rs, alpha_Rs=b0 * (1 + np.log(0.5)), e1=c * np.cos(2 * theta),
               e2=c * np.sin(2 * theta), center_x=0.0, center_y=0.0)]
    lm = LensModel(["NFW_ELLIPSE_POTENTIAL"])
    start = time.perf_counter()
    lax, lay = lm.alpha(x[sub], y[sub], kw)
    lm.hessian(x[sub], y[sub], kw)
    t_lt = (time.perf_counter() - start) * scale
    diff = max(np.abs(lax - nax[sub]).max(), np.abs(lay - nay[sub]).max())
    rec.say()
    rec.say(f"one elliptical NFW, deflection and Hessian, {x.size} points: lensdual "
            f"{t_nfw:.3f} s ({1e9 * t_nfw / x.size:.0f} ns per point), lenstronomy "
            f"NFW_ELLIPSE_POTENTIAL {t_lt:.2f} s ({t_lt / t_nfw:.1f}x); max |delta alpha| = "
            f"{diff:.1e} arcsec")
    rec.write(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
