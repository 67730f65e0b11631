"""Calibration suite of the duality test: pulls, false flags and power per regime.

Run on demand (minutes)::

    python benchmarks/calibration.py [--quick] [--save-dir DIR]
    python benchmarks/calibration.py --from-saves DIR [DIR ...]

``--save-dir`` keeps each cell's per-pair results (``ln(mu_size /
mu_true)``, its error, status, degrees of freedom and flux noise), so that
another error model or flag rule can be judged offline on the same draws.
``--from-saves`` prints the same table from such saves, runs with other
seeds pooled cell by cell (:func:`pooled_cells`): runs of 10 constellations
per cell leave the false-flag rate uncertain by a factor of about 2 at
0.27 %, pooled runs narrow it. A cell where fewer than half of the pairs
are testable ends with a comment on the errors shown for the pairs the test
declines (:func:`declined_metrics`).

For every cell (lens family x position noise) many clean constellations
(no sub-halo, exact true positions from the lens, flux ratios equal to the
true magnification ratio with 1 % errors per image) get Gaussian position
noise, and each estimator is run on them. Reported per cell:

- ``tested``: fraction of pairs the duality test can test (adaptive status
  "ok" or "misfit"; "untestable" pairs are reported but not tested);
- ``ok``: fraction of pairs whose adaptive fit passed its chi-square test;
- ``ffr``: false-flag rate at SNR 3 among tested pairs (nominal 0.27 %),
  flags as :func:`lensdual.duality.check_duality` sets them (significance,
  Student's t for "misfit" pairs); ``ffr_l95`` and ``ffr_u95`` its
  one-sided 95 % lower and upper limits (the looser of a bootstrap over
  whole constellations, whose pairs and noise draws are correlated, and
  the Clopper-Pearson limits of the pooled count);
- ``pull_med``, ``pull_w``: median and robust (16-84 %) half-width of
  ln(mu_size / mu_true) / sigma;
- ``pull_gw``: the same width of the Gaussian-equivalent pulls: a "misfit"
  pair's error is an estimate with ``ln_mu_size_err_dof`` degrees of
  freedom, so its calibrated pull follows Student's t (a 16-84 % half-width
  of 1.14 with 4 degrees of freedom); its pull is mapped to the Gaussian
  quantile of the same tail probability, as the flag reads it (``"ok"``
  pulls are unchanged);
- ``bias``: median of ln(mu_size / mu_true);
- ``sig``: median sigma of ln mu_size;
- ``pow10``, ``pow25``, ``pow50``: fraction of pairs flagged when their
  L1 flux is raised by 10, 25, 50 % (an injected anomaly).

Families: those of :mod:`lensdual.simulation.families` (cluster fold and
cusp with members, a galaxy-scale EPL + shear fold, the SMACS0723 analogue,
the real SMACS0723 Lenstool model, and four CATS Lenstool models added as
lenses the estimator was not developed on, MACS J1149, Abell 2744, Abell
370 and Abell S1063, where ``../shared/data`` is present),
each with 8, 20 and 40 resolvable sources. ``ffr_exact`` uses exact flux
ratios (quoted errors 1 % per image), ``ffr`` noisy ones.
"""

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u
from scipy.stats import beta as beta_dist

from lensdual.duality import _snr_dof, duality_significance, gaussian_p_value
from lensdual.estimators import TESTABLE_STATUS, size_magnification
from lensdual.simulation import FAMILIES, clean_constellation

use_shared_data()

NOISE_MAS = (1, 2, 5, 10, 20)
N_SOURCES = (8, 20, 40)
FLUX_ERR = 0.01  # per image


def constellations(family, n_sources, n_const, seed=0):
    """Clean constellations of a family: (theta1, theta2, mu_true) arrays in arcsec."""
    out = []
    for k in range(n_const):
        t = clean_constellation(family, n_sources, seed=seed + k)
        out.append((np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)]),
                    np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)]),
                    np.asarray(t["mu_true"], dtype=float)))
    return out


def run_cell(constellations, sigma_mas, method, n_noise, seed=0, save=None):
    """One cell: every constellation with ``n_noise`` position-noise draws; its metrics."""
    rng = np.random.default_rng(seed)
    err, sd, status, dof = [], [], [], []
    sig = sigma_mas / 1000.0
    for t1, t2, mu in constellations:
        for _ in range(n_noise):
            o1 = t1 + sig * rng.standard_normal(t1.shape)
            o2 = t2 + sig * rng.standard_normal(t2.shape)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, method,
                                         sigma_pos=sig * u.arcsec, n_bootstrap=200,
                                         seed=int(rng.integers(2**31)))
            err.append(np.log(np.asarray(tab["mu_size"]) / mu))
            sd.append(np.asarray(tab["ln_mu_size_err"]))
            status.append(np.asarray(tab["mu_size_status"]))
            dof.append(np.asarray(tab["ln_mu_size_err_dof"], dtype=float))
    err, sd, status, dof = map(np.concatenate, (err, sd, status, dof))
    ln_flux_noise = np.sqrt(2) * FLUX_ERR * rng.standard_normal(err.size)
    constellation = np.repeat(np.arange(len(constellations)),
                              [n_noise * len(c[2]) for c in constellations])
    if save is not None:
        # per-pair results, for offline analysis of the error model (pairs in
        # constellation order, noise draws within)
        np.savez(save, ln_err=err, ln_sd=sd, status=status.astype(str), dof=dof,
                 ln_flux_noise=ln_flux_noise, constellation=constellation)
    return cell_metrics(err, sd, status, dof, ln_flux_noise, constellation)


def _ffr_limits(n_flag_c, n_tested_c, n_boot=2000, seed=0):
    """One-sided 95 % lower and upper limits of a false-flag rate.

    From per-constellation counts: the pairs of one constellation (and its
    noise draws) are correlated, so the spread over constellations is the
    bootstrap's (resampling whole constellations); with few flags the counts
    are discrete, so the Clopper-Pearson limits of the pooled count too. The
    looser of the two on each side.
    """
    n_flag, n = int(n_flag_c.sum()), int(n_tested_c.sum())
    cp_lo = 0.0 if n_flag == 0 else float(beta_dist.ppf(0.05, n_flag, n - n_flag + 1))
    cp_hi = float(beta_dist.ppf(0.95, n_flag + 1, n - n_flag))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n_flag_c.size, (n_boot, n_flag_c.size))
    rates = n_flag_c[idx].sum(1) / np.maximum(n_tested_c[idx].sum(1), 1)
    bs_lo, bs_hi = np.percentile(rates, [5, 95])
    return min(cp_lo, float(bs_lo)), max(cp_hi, float(bs_hi))


def cell_metrics(err, sd, status, dof, ln_flux_noise, constellation):
    """The metrics of a cell from its per-pair results (see the module docstring)."""
    tested = np.isin(status, TESTABLE_STATUS)
    flux_sd = np.sqrt(2) * FLUX_ERR
    tot = np.hypot(sd, flux_sd)
    tot_dof = _snr_dof(tot, sd, dof)  # the total error's degrees of freedom, as check_duality
    tested &= ~(tot_dof <= 0)

    def flagged(snr):
        """check_duality's flag: significance (Gaussian equivalent) above 3."""
        return duality_significance(snr[tested], tot_dof[tested]) > 3

    pull = err / sd
    gpull = np.full_like(pull, np.nan)
    gpull[tested] = np.sign(pull[tested]) * duality_significance(np.abs(pull[tested]),
                                                                 dof[tested])
    out = {"n": int(tested.sum()), "tested": float(tested.mean()),
           "ok": float(np.mean(status == "ok"))}
    if not tested.any():
        nan = float("nan")
        out.update(ffr=nan, ffr_l95=nan, ffr_u95=nan, ffr_exact=nan, pull_med=nan, pull_w=nan,
                   pull_gw=nan, bias=nan, sig=nan, pow10=nan, pow25=nan, pow50=nan)
        return out
    snr0 = np.abs(ln_flux_noise - err) / tot
    flags = np.zeros(err.size, dtype=bool)
    flags[tested] = flagged(snr0)
    out["ffr"] = int(flags.sum()) / out["n"]
    n_c = int(constellation.max()) + 1
    out["ffr_l95"], out["ffr_u95"] = _ffr_limits(
        np.bincount(constellation, flags, n_c), np.bincount(constellation, tested, n_c))
    out["ffr_exact"] = float(np.mean(flagged(np.abs(err) / tot)))
    q16, q50, q84 = np.percentile(pull[tested], [15.87, 50, 84.13])
    g16, g84 = np.percentile(gpull[tested], [15.87, 84.13])
    out.update(pull_med=q50, pull_w=0.5 * (q84 - q16), pull_gw=0.5 * (g84 - g16),
               bias=float(np.median(err[tested])),
               sig=float(np.median(sd[tested])))
    for a in (0.10, 0.25, 0.50):
        snr = np.abs(np.log1p(a) + ln_flux_noise - err) / tot
        out[f"pow{int(a * 100)}"] = float(np.mean(flagged(snr)))
    out["nominal"] = float(gaussian_p_value(3.0))
    return out


def declined_metrics(err, sd, status, dof):
    """The errors shown for the pairs the test declines (not in ``TESTABLE_STATUS``):
    the Gaussian-equivalent width of their pulls and the fraction beyond 3 sigma."""
    declined = ~np.isin(status, TESTABLE_STATUS) & np.isfinite(sd) & (sd > 0) & (dof > 0)
    if not declined.any():
        return {"n": 0, "gw": float("nan"), "beyond3": float("nan")}
    pull = err[declined] / sd[declined]
    gpull = np.sign(pull) * duality_significance(np.abs(pull), dof[declined])
    g16, g84 = np.percentile(gpull, [15.87, 84.13])
    return {"n": int(declined.sum()), "gw": float(0.5 * (g84 - g16)),
            "beyond3": float(np.mean(np.abs(gpull) > 3))}


def pooled_cells(dirs):
    """Per-pair saves of several runs (``--save-dir``), pooled cell by cell.

    Yields ``(name, n_sources, method, noise_mas, metrics)`` for every cell
    file found in any of ``dirs``, its constellations numbered apart run by
    run (so that the limits resample whole constellations of every run).
    """
    names = sorted({p.stem for d in dirs for p in Path(d).glob("*.npz")})
    for stem in names:
        parts, offset = [], 0
        for d in dirs:
            path = Path(d) / f"{stem}.npz"
            if not path.exists():
                continue
            with np.load(path) as z:
                part = {k: z[k] for k in z.files}
            part["constellation"] = part["constellation"] + offset
            offset = int(part["constellation"].max()) + 1
            parts.append(part)
        pooled = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        name, n_src, method, noise = stem.rsplit("_", 3)
        metrics = cell_metrics(pooled["ln_err"], pooled["ln_sd"], pooled["status"],
                               pooled["dof"], pooled["ln_flux_noise"], pooled["constellation"])
        metrics["declined"] = declined_metrics(pooled["ln_err"], pooled["ln_sd"],
                                               pooled["status"], pooled["dof"])
        yield name, int(n_src), method, float(noise), metrics


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer constellations")
    parser.add_argument("--methods", default="adaptive,quad2")
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--n-sources", default=",".join(map(str, N_SOURCES)))
    parser.add_argument("--noise", default=",".join(map(str, NOISE_MAS)))
    parser.add_argument("--n-const", type=int, default=None,
                        help="constellations per cell (default 10, --quick 5)")
    parser.add_argument("--n-noise", type=int, default=None,
                        help="noise draws per constellation (default 10, --quick 5)")
    parser.add_argument("--seed", type=int, default=0, help="first constellation seed")
    parser.add_argument("--from-saves", nargs="+", default=None, metavar="DIR",
                        help="print the table from the per-pair saves of earlier runs "
                             "(--save-dir), pooled cell by cell; runs nothing")
    parser.add_argument("--save-dir", default=None,
                        help="save each cell's per-pair results (ln(mu_size / mu_true), "
                             "its error, status, degrees of freedom, flux noise) as "
                             "FAMILY_N_METHOD_NOISE.npz in this folder")
    args = parser.parse_args(argv)
    cols = ("n", "tested", "ok", "ffr", "ffr_l95", "ffr_u95", "ffr_exact", "pull_med", "pull_w",
            "pull_gw", "bias", "sig", "pow10", "pow25", "pow50")
    if args.from_saves:
        missing = [d for d in args.from_saves if not Path(d).is_dir()]
        if missing:
            parser.error(f"--from-saves: no such folder: {', '.join(missing)}")
        print("family n_sources method noise_mas " + " ".join(cols))
        for name, n_src, method, s, r in pooled_cells(args.from_saves):
            line = f"{name} {n_src} {method} {s:g} " + " ".join(f"{r[c]:.3g}" for c in cols)
            if r["tested"] < 0.5:
                d = r["declined"]
                line += (f"  # declined {d['n']} pairs: width {d['gw']:.3g}, "
                         f"beyond 3 sigma {d['beyond3']:.3g}")
            print(line)
        return
    if args.save_dir is not None:
        Path(args.save_dir).mkdir(parents=True, exist_ok=True)
    n_const, n_noise = (5, 5) if args.quick else (10, 10)
    n_const = args.n_const or n_const
    n_noise = args.n_noise or n_noise
    print("family n_sources method noise_mas " + " ".join(cols))
    for name in args.families.split(","):
        for n_src in map(int, args.n_sources.split(",")):
            try:
                cons = constellations(name, n_src, n_const, seed=args.seed)
            except (FileNotFoundError, RuntimeError) as exc:
                print(f"# {name} N={n_src}: skipped ({exc})")
                continue
            for method in args.methods.split(","):
                for s in map(float, args.noise.split(",")):
                    t0 = time.perf_counter()
                    save = (None if args.save_dir is None else
                            Path(args.save_dir) / f"{name}_{n_src}_{method}_{s:g}.npz")
                    r = run_cell(cons, s, method, n_noise, save=save)
                    print(f"{name} {n_src} {method} {s:g} "
                          + " ".join(f"{r[c]:.3g}" for c in cols)
                          + f"  # {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
