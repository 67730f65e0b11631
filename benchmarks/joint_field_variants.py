"""Error models of the joint test's flux field, judged on the same draws.

Run on demand (about 10 minutes per variant on one core)::

    python benchmarks/joint_field_variants.py VARIANT [--families F1,F2]
        [--n-const 150] [--noise 5,20] [--n-sources 20,40] [--output FILE]

The flux field (:mod:`lensdual.flux_field`) is recomputed here in plain numpy
(the same local fits, steps 0 to 4, step 1's drop of outlying neighbours included)
with the variance of step 2 replaced:

- ``bound``: the squared difference ``d^2`` of the quadratic's and the
  cubic's predictions;
- ``eb``: the library's rule (checked against
  :func:`lensdual.flux_field.field_arrays` on a random constellation, first
  line of the output), an empirical-Bayes estimate of the squared bias. The bias of the
  quadratic at pair ``i`` is given a prior ``N(0, tau^2 G_i)``, where ``G_i``
  is the squared norm of the quadratic's prediction weights applied to the
  cubic monomials of its neighbours (how much cubic terms move the
  prediction), ``d_i`` is that bias plus noise of known variance ``V_i`` (the
  two predictions' weights applied to the neighbours' errors), ``tau^2`` is
  the maximum-likelihood value over the constellation's pairs, and the
  variance added is the posterior mean of the squared bias,
  ``k^2 d_i^2 + k V_i`` with ``k = tau^2 G_i / (tau^2 G_i + V_i)``;
- ``honest``: ``eb``, with the common model variance of step 4 added only
  where the leave-one-out residuals are significantly wider than their
  errors (more of them beyond 0.674 sigma than a binomial(n, 1/2) gives at
  the 5 % level).

Every cell (family x sources x position noise, 2 % flux errors) goes
through ``benchmarks/joint_calibration.py``'s ``run_cell`` with the variant
in place of the library's field; the columns are those of that benchmark
(false flags at SNR 3 with the 95 % lower limit, the field's pull width,
power on a 25 % anomaly, joint and geometric).
"""

import argparse
import time

import numpy as np
from _output import Record, add_output_argument
from _shared_data import use_shared_data
from joint_calibration import run_cell
from scipy.optimize import minimize_scalar
from scipy.stats import binom

import lensdual.flux_field as ff
from lensdual.simulation import clean_constellation

use_shared_data()

VARIANTS = ("bound", "eb", "honest")
#: Level of step 4's test of the leave-one-out residuals' width (``honest``).
STEP4_LEVEL = 0.05
#: Search interval of ln tau^2 (``eb``, ``honest``).
LN_TAU2_BOUNDS = (-40.0, 5.0)


def _monomials(x, y, degree):
    return np.array([x ** (k - j) * y**j for k in range(degree + 1)
                     for j in range(k + 1)]).T


def _gradient(x, y, degree, coef):
    gx = np.zeros_like(x)
    gy = np.zeros_like(x)
    c = 0
    for k in range(degree + 1):
        for j in range(k + 1):
            if k - j > 0:
                gx += coef[c] * (k - j) * x ** (k - j - 1) * y**j
            if j > 0:
                gy += coef[c] * j * x ** (k - j) * y ** (j - 1)
            c += 1
    return gx, gy


def _weighted_fit(dw, y, s, degree):
    design = _monomials(dw[:, 0], dw[:, 1], degree) / s[:, None]
    rows = np.linalg.pinv(design)
    return rows @ (y / s), rows[0] / s


def _local_fit(d, y, s, sig_target, sig, degree):
    """One neighbourhood's whitened fit, refitted with the neighbours' errors
    widened by their position errors times the fitted gradient."""
    whiten = np.linalg.cholesky(np.linalg.inv(d.T @ d / len(y)))
    dw = d @ whiten
    coef, _ = _weighted_fit(dw, y, s, degree)
    gx, gy = _gradient(dw[:, 0], dw[:, 1], degree, coef)
    grad = np.column_stack([gx, gy]) @ whiten.T
    s_eff = np.sqrt(s**2 + sig**2 * (grad**2).sum(1))
    coef, a = _weighted_fit(dw, y, s_eff, degree)
    g0 = np.array([coef[1], coef[2]]) @ whiten.T
    return {"value": coef[0], "a": a, "s_eff": s_eff, "var_stat": np.sum(a**2 * s_eff**2),
            "y": y,
            "var_pos": sig_target**2 * (g0**2).sum(), "dw": dw}


def _worst_neighbour(fit):
    """The neighbour of the quadratic ``fit`` (:func:`_local_fit`) whose residual from
    the fit without it, over its standard deviation and over the scale of the
    others' residuals (at least 1), is the largest, and that ratio."""
    dw, y, s = fit["dw"], fit["y"], fit["s_eff"]
    m = len(y)
    p = 6
    t = np.zeros(m)
    for k in range(m):
        rest = np.arange(m) != k
        design = _monomials(dw[rest, 0], dw[rest, 1], 2) / s[rest, None]
        coef = np.linalg.lstsq(design, y[rest] / s[rest], rcond=None)[0]
        x_k = _monomials(dw[k:k + 1, 0], dw[k:k + 1, 1], 2)[0]
        chi2 = np.sum((design @ coef - y[rest] / s[rest]) ** 2)
        scale = max(1.0, chi2 / (m - 1 - p)) if m - 1 - p > 0 else 1.0
        var = s[k] ** 2 + x_k @ np.linalg.pinv(design.T @ design) @ x_k
        t[k] = abs(y[k] - x_k @ coef) / np.sqrt(var * scale)
    return int(np.argmax(t)), float(t.max())


def components(pos, y, s, sig2, usable, resolved):
    """Per pair: the quadratic's and the cubic's predictions, the quadratic's
    variance (statistical and position), the noise variance of their
    difference and the cubic sensitivity ``G``; and the status codes."""
    n = y.size
    out = {k: np.full(n, np.nan) for k in ("v2", "v3", "var", "var_d", "G")}
    code = np.zeros(n, dtype=int)
    for i in range(n):
        others = np.array([j for j in range(n) if usable[j] and j != i], dtype=int)
        if others.size < ff._MIN_CHECK:
            code[i] = 1
            continue
        order = others[np.argsort(np.hypot(*(pos[others] - pos[i]).T), kind="mergesort")]
        if not resolved[i] or np.sum(~resolved[order[:ff.N_LOCAL]]) > ff.MAX_UNRESOLVED:
            code[i] = 2
            continue
        # step 1's drop of neighbours off the quadratic through the others
        order = list(order)
        for n_drop in range(ff.MAX_DROP + 1):
            if len(order) < ff._MIN_CHECK:
                break
            m2, m3 = min(ff.N_LOCAL, len(order)), min(ff.N_CHECK, len(order))
            d = pos[order[:m3]] - pos[i]
            idx = order[:m2]
            f2 = _local_fit(d[:m2], y[idx], s[idx], sig2[i], sig2[idx], 2)
            if n_drop == ff.MAX_DROP:
                break
            worst, t_max = _worst_neighbour(f2)
            if t_max <= ff._T_DROP:
                break
            order.pop(worst)
        if len(order) < ff._MIN_CHECK:
            code[i] = 1
            continue
        f3 = _local_fit(d, y[order[:m3]], s[order[:m3]], sig2[i], sig2[order[:m3]], 3)
        a2 = np.zeros(m3)
        a2[:m2] = f2["a"]
        s_eff = np.maximum(f3["s_eff"], np.concatenate([f2["s_eff"], f3["s_eff"][m2:]]))
        cubic = _monomials(f2["dw"][:, 0], f2["dw"][:, 1], 3)[:, 6:]
        out["v2"][i], out["v3"][i] = f2["value"], f3["value"]
        out["var"][i] = f2["var_stat"] + f2["var_pos"]
        out["var_d"][i] = np.sum((a2 - f3["a"]) ** 2 * s_eff**2)
        out["G"][i] = np.sum((f2["a"] @ cubic) ** 2)
    return out, code


def bias_variance(c, calib, variant):
    """The variance step 2 adds, per pair, under ``variant``."""
    d = c["v2"] - c["v3"]
    if variant == "bound":
        return d**2
    ok = calib & np.isfinite(d)

    def nll(ln_tau2):
        v = np.exp(ln_tau2) * c["G"][ok] + c["var_d"][ok]
        return 0.5 * np.sum(np.log(v) + d[ok] ** 2 / v)

    tau2 = np.exp(minimize_scalar(nll, bounds=LN_TAU2_BOUNDS, method="bounded").x)
    k = tau2 * c["G"] / (tau2 * c["G"] + c["var_d"])
    return k**2 * d**2 + k * c["var_d"]


def model_variance(resid, var, variant):
    """Step 4's common model variance under ``variant``."""
    if variant == "honest":
        z = np.abs(resid) / np.sqrt(var)
        wide = int(np.sum(z > ff._GAUSS_MEDIAN_ABS))
        if z.size < ff._MIN_CALIBRATION or binom.sf(wide - 1, z.size, 0.5) >= STEP4_LEVEL:
            return 0.0
    return ff._common_variance(resid, var)


def field_arrays_of(variant):
    """A stand-in for :func:`lensdual.flux_field.field_arrays` under ``variant``."""
    def field_arrays(pos, y, s, sig2, usable=None, resolved=None):
        n = y.size
        placed = np.isfinite(pos).all(axis=1)
        finite = np.isfinite(y) & np.isfinite(s) & (s > 0) & placed
        usable = finite if usable is None else usable & finite
        resolved = np.ones(n, dtype=bool) if resolved is None else resolved
        c, code = components(np.where(placed[:, None], pos, 0.0), np.where(finite, y, 0.0),
                             np.where(finite, s, 1.0), sig2, usable, resolved)
        ok = (code == 0) & placed & np.isfinite(c["v2"])
        calib = ok & usable
        var = c["var"] + bias_variance(c, calib, variant)
        model_var = model_variance(y[calib] - c["v2"][calib], s[calib] ** 2 + var[calib],
                                   variant)
        status = np.where(placed, np.asarray(ff.FIELD_STATUS)[code], "excluded")
        return ff._Field(np.where(ok, c["v2"], np.nan), np.where(ok, var + model_var, np.nan),
                         status, np.where(ok, np.minimum(ff.N_CHECK, n - 1), 0),
                         np.zeros(n, dtype=int), model_var)
    return field_arrays


def check(n=30, seed=1):
    """How closely the ``eb`` variant reproduces the library's field on a random
    constellation (the largest difference of the values, the largest relative one
    of the variances; the number of neighbours the library dropped)."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-1, 1, (n, 2))
    y = 0.3 * pos[:, 0] + 0.2 * pos[:, 0] * pos[:, 1] ** 2 + rng.normal(0, 0.02, n)
    y[[3, 17]] += 0.25  # two anomalies, which step 1 drops from their neighbours' fits
    s = np.full(n, 0.02)
    sig2 = np.full(n, 0.01)
    lib = ff.field_arrays(pos, y, s, sig2)
    mine = field_arrays_of("eb")(pos, y, s, sig2)
    return float(np.nanmax(np.abs(lib.value - mine.value))), float(
        np.nanmax(np.abs(lib.var / mine.var - 1))), int(lib.n_dropped.sum())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variant", choices=VARIANTS)
    parser.add_argument("--families", default="cluster_fold,smacs_analog,smacs_lenstool,"
                        "galaxy_fold,cluster_cusp,macs1149_lenstool,a2744_lenstool,"
                        "a370_lenstool,as1063_lenstool,as1063_s13_lenstool")
    parser.add_argument("--n-const", type=int, default=150)
    parser.add_argument("--noise", default="5,20", help="position noise, mas")
    parser.add_argument("--n-sources", default="20,40")
    parser.add_argument("--flux-err", type=float, default=0.02)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    dv, dr, n_drop = check()
    rec.say(f"# variant {args.variant}; {args.n_const} constellations per cell; flux error "
             f"{args.flux_err:g}; 'eb' against the library: value {dv:.1e}, variance {dr:.1e} "
            f"({n_drop} neighbours dropped)")
    ff.field_arrays = field_arrays_of(args.variant)
    rec.say("family n_sources noise_mas field ffr ffr_l95 field_pull_w pow25 pow25_geo")
    for name in args.families.split(","):
        for n_src in map(int, args.n_sources.split(",")):
            tables = [clean_constellation(name, n_src, seed=k) for k in range(args.n_const)]
            for s in map(float, args.noise.split(",")):
                t0 = time.perf_counter()
                r = run_cell(tables, s, args.flux_err, 1, False)
                rec.say(f"{name} {n_src} {s:g} " + " ".join(
                    f"{r[c]:.4g}" for c in ("field", "ffr", "ffr_l95", "field_pull_w", "pow25",
                                            "pow25_geo"))
                    + f"  # {time.perf_counter() - t0:.0f} s")
    rec.write(args.output)


if __name__ == "__main__":
    main()
