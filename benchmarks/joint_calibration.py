"""Calibration of the joint duality test (geometry and the neighbours' flux ratios).

Run on demand (minutes per family)::

    python benchmarks/joint_calibration.py [--families F1,F2] [--n-const 50]
        [--snr-definition conservative] [--fainter]

For every cell (lens family x number of sources x position noise x flux
error) clean constellations (:func:`lensdual.simulation.clean_constellation`,
no sub-halo) get Gaussian position noise on both arcs and Gaussian flux noise
on every image and band (two bands), and go through
``check_duality(..., test="joint")``. Reported per cell:

- ``tested``: fraction of pairs the joint test tests; ``field``: fraction with
  a flux-field prediction (``field_status`` ``"ok"``); ``fails``: fraction
  reported ``smooth_field_fails``;
- ``ffr``: false-flag rate at significance 3 among tested pairs (nominal
  0.27 %), with its one-sided 95 % limits ``ffr_l95``, ``ffr_u95`` (as in
  ``calibration.py``: the looser of a bootstrap over constellations and the
  Clopper-Pearson limits); ``ffr_geo``: the geometric test's on the same
  draws;
- ``field_pull_w``: robust (16-84 %) half-width of
  ``(ln_mu_field - ln mu_true) / ln_mu_field_err``;
- ``pow25``, ``pow25_geo``: fraction of the pairs flagged when the pair's L1
  fluxes are raised by 25 % (each pair in turn; the joint test's prediction
  of a pair does not use the pair's own flux, so this is the joint pass of
  :mod:`lensdual.duality` applied to the raised flux ratio), joint and
  geometric, among all pairs;
- ``mask25`` (``--masking``): two nearest-neighbour pairs both raised by 25 %
  (one such pair of pairs per draw, run through ``check_duality``): fraction
  of draws in which both are flagged.
"""

import argparse
import time
import warnings

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u
from calibration import _ffr_limits

from lensdual.duality import LOG_SNR_DEFINITIONS, _joint_pass, _profile_of, check_duality
from lensdual.simulation import FAMILIES, clean_constellation, noisy_constellation

use_shared_data()

ANOMALY = np.log(1.25)


def _raise_l1(t, rows, factor=1.25):
    t = t.copy()
    for band in t.meta["bands"]:
        for k in rows:
            t[f"flux1_{band}"][k] *= factor
    return t


def _power(r, snr_threshold=3.0, snr_definition="log"):
    """Joint and geometric flags of every pair with its L1 flux raised by 25 %."""
    profile = _profile_of(r) if snr_definition == "conservative" else None
    ln_flux = np.log(np.asarray(r["mu_flux"], dtype=float)) + ANOMALY
    ln_flux_err = np.asarray(r["mu_flux_err"], dtype=float) / np.asarray(r["mu_flux"], float)
    g_ok = np.isin(np.asarray(r["mu_size_status"]), ("ok", "misfit"))
    geo = (np.log(np.asarray(r["mu_size"], dtype=float)),
           np.asarray(r["ln_mu_size_err"], dtype=float) ** 2,
           np.asarray(r["ln_mu_size_err_dof"], dtype=float), g_ok)
    f_ok = np.asarray(r["field_status"]) == "ok"
    field = (np.asarray(r["ln_mu_field"], dtype=float),
             np.asarray(r["ln_mu_field_err"], dtype=float) ** 2, f_ok)
    _, _, signif, tested, *_ = _joint_pass(ln_flux, ln_flux_err, geo, field, snr_threshold,
                                           profile)
    joint = tested & (signif > snr_threshold)
    geo_only = _joint_pass(ln_flux, ln_flux_err, geo,
                           (field[0], field[1], np.zeros_like(f_ok)), snr_threshold, profile)
    geo_flag = geo_only[3] & (geo_only[2] > snr_threshold)
    return joint, geo_flag


def run_cell(tables, sigma_mas, flux_err, n_noise, masking, seed=0, snr_definition="log"):
    rng = np.random.default_rng(seed)
    sigma = sigma_mas / 1000.0
    acc = {k: [] for k in ("tested", "field", "fails", "flag", "flag_geo", "tested_geo",
                           "pull", "pow", "pow_geo", "const")}
    masked = []
    for c, table in enumerate(tables):
        mu_true = np.asarray(table["mu_true"], dtype=float)
        for _ in range(n_noise):
            t = noisy_constellation(table, sigma_pos=sigma * u.arcsec, flux_rel_err=flux_err,
                                    seed=rng)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = check_duality(t, sigma_pos=sigma * u.arcsec, test="joint",
                                  snr_definition=snr_definition)
            f_ok = np.asarray(r["field_status"]) == "ok"
            acc["tested"].append(np.asarray(r["tested"], dtype=bool))
            acc["field"].append(f_ok)
            acc["fails"].append(np.asarray(r["smooth_field_fails"], dtype=bool))
            acc["flag"].append(np.asarray(r["anomalous"], dtype=bool))
            acc["flag_geo"].append(np.asarray(r["anomalous_geometric"], dtype=bool))
            acc["tested_geo"].append(np.isfinite(np.asarray(r["significance_geometric"],
                                                            dtype=float)))
            pull = (np.asarray(r["ln_mu_field"], float) - np.log(mu_true)) \
                / np.asarray(r["ln_mu_field_err"], float)
            acc["pull"].append(np.where(f_ok, pull, np.nan))
            joint, geo_flag = _power(r, snr_definition=snr_definition)
            acc["pow"].append(joint)
            acc["pow_geo"].append(geo_flag)
            acc["const"].append(np.full(len(r), c))
            if masking:
                xy = np.column_stack([table["x2"].to_value(u.arcsec),
                                      table["y2"].to_value(u.arcsec)])
                a = int(rng.integers(len(table)))
                d = np.hypot(*(xy - xy[a]).T)
                d[a] = np.inf
                b = int(np.argmin(d))
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    rm = check_duality(_raise_l1(t, (a, b)), sigma_pos=sigma * u.arcsec,
                                       test="joint", snr_definition=snr_definition)
                masked.append(bool(rm["anomalous"][a] and rm["anomalous"][b]))
    cat = {k: np.concatenate(v) for k, v in acc.items()}
    tested, const = cat["tested"], cat["const"]
    n_c = int(const.max()) + 1
    out = {"n": int(tested.sum()), "tested": tested.mean(), "field": cat["field"].mean(),
           "fails": cat["fails"].mean()}
    out["ffr"] = cat["flag"][tested].mean() if tested.any() else np.nan
    out["ffr_l95"], out["ffr_u95"] = _ffr_limits(np.bincount(const, cat["flag"], n_c),
                                                 np.bincount(const, tested, n_c))
    tg = cat["tested_geo"]
    out["ffr_geo"] = cat["flag_geo"][tg].mean() if tg.any() else np.nan
    pull = cat["pull"][np.isfinite(cat["pull"])]
    out["field_pull_w"] = (0.5 * np.subtract(*np.percentile(pull, [84.13, 15.87]))
                           if pull.size else np.nan)
    out["pow25"] = cat["pow"].mean()
    out["pow25_geo"] = cat["pow_geo"].mean()
    out["mask25"] = float(np.mean(masked)) if masked else np.nan
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--n-sources", default="20,40")
    parser.add_argument("--noise", default="1,5,20", help="position noise, mas")
    parser.add_argument("--flux-err", default="0.02,0.05", help="relative, per image and band")
    parser.add_argument("--n-const", type=int, default=50, help="constellations per cell")
    parser.add_argument("--n-noise", type=int, default=1, help="noise draws per constellation")
    parser.add_argument("--seed", type=int, default=0, help="first constellation seed")
    parser.add_argument("--masking", action="store_true",
                        help="also the two-neighbour masking trial (a second run per draw)")
    parser.add_argument("--snr-definition", default="log", choices=LOG_SNR_DEFINITIONS,
                        help="check_duality's snr_definition")
    parser.add_argument("--fainter", action="store_true",
                        help="the power columns on a 20 %% fainter L1 image instead of a 25 %% "
                             "brighter one (still named pow25, pow25_geo)")
    args = parser.parse_args(argv)
    global ANOMALY
    if args.fainter:
        ANOMALY = np.log(0.8)
    cols = ("n", "tested", "field", "fails", "ffr", "ffr_l95", "ffr_u95", "ffr_geo",
            "field_pull_w", "pow25", "pow25_geo", "mask25")
    print("family n_sources noise_mas flux_err " + " ".join(cols))
    for name in args.families.split(","):
        for n_src in map(int, args.n_sources.split(",")):
            try:
                tables = [clean_constellation(name, n_src, seed=args.seed + k)
                          for k in range(args.n_const)]
            except (FileNotFoundError, RuntimeError) as exc:
                print(f"# {name} N={n_src}: skipped ({exc})")
                continue
            for s in map(float, args.noise.split(",")):
                for fe in map(float, args.flux_err.split(",")):
                    t0 = time.perf_counter()
                    r = run_cell(tables, s, fe, args.n_noise, args.masking,
                                 snr_definition=args.snr_definition)
                    print(f"{name} {n_src} {s:g} {fe:g} "
                          + " ".join(f"{r[c]:.3g}" for c in cols)
                          + f"  # {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
