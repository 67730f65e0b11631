"""Injection and recovery of the sub-halo abundance and the WDM half-mode mass.

Run on demand (minutes)::

    python benchmarks/inference_half_mode_coverage.py [--family smacs_analog]
        [--n-universes 100] [--n-systems 5] [--n-real 500] [--n-calibration 300]
        [--log-m-host 15] [--out FILE]

One clean constellation of ``--family`` (20 sources) and the forward model of
its pairs for WDM populations at log10 m_hm = 5, 6, ..., 10
(:func:`simulate_anomalies`, ``--n-real`` realisations on 15 abundances
log-spaced over 1e-3 to 0.3 kpc^-2); the composite weight
(:func:`composite_weight`) of the lightest half-mode mass. Then
``--n-universes`` mock universes: ``sigma_sub`` and log10 m_hm drawn from the
log-uniform priors (the half-mode mass between the grid's ends, not only on
its nodes), ``--n-systems`` mock constellations each (one WDM realisation at
the truth and its own noise, seeds the forward model never used, 10 mas and
2 % flux errors), ``check_duality`` (the geometric test, linearised SNR) and
:func:`half_mode_posterior`, with the composite weight and, with
``--n-calibration`` above 0, with weight 1 recalibrated on that many mocks of
each constellation (:func:`calibrate_posterior` on the forward models of every
half-mode mass, each constellation with its own seed). Reported per
posterior: how often the marginals' 68 % and 95 % equal-tailed intervals hold
the truth (targets 68 +- 5 % and 95 +- 3 %), for ``sigma_sub`` and for log10
m_hm, the median of log10(posterior median / truth) of ``sigma_sub``, and the
median width of the half-mode mass's 95 % interval against the prior's; for
the calibration, also how often its mocks' uncalibrated intervals held their
truths.
"""

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u

from lensdual import check_duality
from lensdual.inference import (
    SubhaloPopulation,
    apply_population,
    calibrate_posterior,
    composite_weight,
    half_mode_posterior,
    simulate_anomalies,
)
from lensdual.simulation import noisy_constellation
from lensdual.simulation.families import calibration_system, clean_constellation

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

PRIOR_SIGMA = (1e-3, 0.3)  # kpc^-2
LOG_MHM = (5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
SIGMA_POS = 10 * u.mas
FLUX_ERR = 0.02


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", default="smacs_analog")
    p.add_argument("--n-universes", type=int, default=100)
    p.add_argument("--n-systems", type=int, default=5)
    p.add_argument("--n-real", type=int, default=500)
    p.add_argument("--n-grid", type=int, default=15)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--n-calibration", type=int, default=300,
                   help="mocks of each constellation's calibration (0: none)")
    p.add_argument("--log-m-host", type=float, default=15.0)
    p.add_argument("--out", default=None)
    args = p.parse_args()
    use_shared_data()
    system, info = calibration_system(args.family)
    pairs = clean_constellation(args.family, 20, seed=args.seed)
    zl, zs = info["z_lens"], info["z_source"]
    grid = np.geomspace(*PRIOR_SIGMA, args.n_grid) / u.kpc**2
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        sims = [simulate_anomalies(pairs, system,
                                   SubhaloPopulation(zl, zs, model="WDM", log_mhm=m,
                                                     log_m_host=args.log_m_host), grid,
                                   n_realisations=args.n_real, seed=args.seed, client=pool)
                for m in LOG_MHM]
    weight = composite_weight(pairs, system, sims[0], sigma_pos=SIGMA_POS,
                              flux_rel_err=FLUX_ERR, n_mocks=100, seed=args.seed + 7,
                              **GEOMETRIC)
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrations = None
    if args.n_calibration:
        with ThreadPoolExecutor(2) as pool:
            calibrations = [calibrate_posterior(pairs, system, sims, sigma_pos=SIGMA_POS,
                                                flux_rel_err=FLUX_ERR,
                                                n_mocks=args.n_calibration,
                                                seed=args.seed + 11 + j, client=pool,
                                                **GEOMETRIC)
                            for j in range(args.n_systems)]
    t_calib = time.perf_counter() - t0
    rng = np.random.default_rng(args.seed + 1)
    rows = {}
    t0 = time.perf_counter()
    for k in range(args.n_universes):
        truth_s = 10 ** rng.uniform(*np.log10(PRIOR_SIGMA))
        truth_m = rng.uniform(LOG_MHM[0], LOG_MHM[-1])
        pop = SubhaloPopulation(zl, zs, model="WDM", log_mhm=truth_m,
                                log_m_host=args.log_m_host)
        tables = []
        for j in range(args.n_systems):
            mock = apply_population(pairs, system, pop, truth_s / u.kpc**2,
                                    seed=10_000 + 100 * k + j)
            noisy = noisy_constellation(mock, sigma_pos=SIGMA_POS, flux_rel_err=FLUX_ERR,
                                        seed=50_000 + 100 * k + j)
            tables.append(check_duality(noisy, sigma_pos=SIGMA_POS, seed=j, **GEOMETRIC))
        per_mass = [[s] * args.n_systems for s in sims]
        posts = {"": half_mode_posterior(tables, per_mass, weights=[weight] * args.n_systems)}
        if calibrations is not None:
            posts["calibrated "] = half_mode_posterior(tables, per_mass,
                                                       calibrations=calibrations)
        flags = sum(int(t["anomalous"].sum()) for t in tables)
        for key, post in posts.items():
            m = post.meta["inference"]
            s68 = m["interval_68"].to_value(u.kpc**-2)
            s95 = m["interval_95"].to_value(u.kpc**-2)
            m68, m95 = m["log10_mhm_interval_68"], m["log10_mhm_interval_95"]
            rows.setdefault(key, []).append((
                s68[0] <= truth_s <= s68[1], s95[0] <= truth_s <= s95[1],
                m68[0] <= truth_m <= m68[1], m95[0] <= truth_m <= m95[1],
                np.log10(m["median"].to_value(u.kpc**-2) / truth_s), m95[1] - m95[0], flags,
                np.log10(s95[1] / s95[0])))
            if key:
                calibration_meta = m
    t_uni = time.perf_counter() - t0
    lines = [f"# {vars(args)}",
             f"{args.family}: {args.n_universes} universes x {args.n_systems} constellations, "
             f"20 sources, {SIGMA_POS.value:g} mas, {100 * FLUX_ERR:g} % flux; WDM forward "
             f"models at log10 m_hm = {', '.join(f'{x:g}' for x in LOG_MHM)}, {args.n_real} x "
             f"{args.n_grid}; composite weight {weight:.3f}"
             + (f"; calibrated on {args.n_calibration} mocks per constellation"
                if calibrations else "")
             + f"; t_sim={t_sim:.0f}s t_calibration={t_calib:.0f}s t_universes={t_uni:.0f}s"]
    for key, rr in rows.items():
        r = np.array(rr, dtype=float)
        n = len(r)

        def cov(col, r=r, n=n):
            c = r[:, col].mean()
            return f"{c:.3f} (+-{np.sqrt(c * (1 - c) / n):.3f})"

        lines += [f"  {key}sigma_sub  cov68={cov(0)} cov95={cov(1)} "
                  f"bias_median={np.median(r[:, 4]):+.3f} dex "
                  f"width95={np.median(r[:, 7]):.2f} dex",
                  f"  {key}log10_mhm  cov68={cov(2)} cov95={cov(3)} "
                  f"width95={np.median(r[:, 5]):.2f} (prior {LOG_MHM[-1] - LOG_MHM[0]:g})"]
        if key:
            s, mm = (calibration_meta["mock_coverage_uncalibrated"],
                     calibration_meta["log10_mhm_mock_coverage_uncalibrated"])
            lines.append(f"      the calibration's mocks ({calibration_meta['n_mocks']} used): "
                         f"uncalibrated sigma_sub cov68={s['68']:.3f} cov95={s['95']:.3f}, "
                         f"log10_mhm cov68={mm['68']:.3f} cov95={mm['95']:.3f}")
    lines.append(f"  flags per universe: median {np.median(np.array(rows[''])[:, 6]):.0f}")
    print("\n".join(lines))
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
