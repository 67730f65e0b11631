"""Injection and recovery of the sub-halo abundance (lensdual.inference).

Run on demand (minutes per family)::

    python benchmarks/inference_coverage.py [--families F1,F2] [--n-universes 100]
        [--n-sources 20] [--sigma-pos-mas 10] [--flux-rel-err 0.02]
        [--test {geometric,joint}] [--los-normalization 1] [--n-calibration 300]
        [--out FILE]

Per family: one clean constellation (:func:`clean_constellation`) in the
family's smooth lens, the forward model of its pairs
(:func:`simulate_anomalies`, ``--n-real`` realisations on ``--n-grid``
abundances log-spaced over the prior, 1e-3 to 0.3 kpc^-2), then
``--n-universes`` mock universes: ``sigma_sub`` drawn from the log-uniform
prior, one pyHalo CDM realisation at it applied to the fluxes
(:func:`apply_population`, a seed the forward model never used), Gaussian
position and flux noise, ``check_duality`` (``--test``: the default,
geometric test, or the joint test, whose prediction also uses the
neighbours' flux ratios) and the posterior, both with weight 1 (the pairs'
errors taken as independent) and with the constellation's composite weight
(:func:`composite_weight`, from ``--n-mocks`` other mocks, each tested with
the same test), and, with ``--n-calibration`` above 0, recalibrated on that
many further mocks (:func:`calibrate_posterior`, weight 1). Reported per
posterior: the fraction of universes
whose 68 % and 95 % equal-tailed intervals hold the truth (targets 68 +- 5 %
and 95 +- 3 %), the fractions of truths below and above the 95 % interval,
the median and the mean of log10(posterior median / truth) (target: at most
0.1 dex), the median 95 % interval width in dex, the fraction of universes
without a flag; also the paper's binomial bound (Sect. 5.4, 1e8 Msun, zeta =
3) for the same number of tested sources.
"""

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u

from lensdual import check_duality
from lensdual.abundance import detection_probability_limit, surface_density_limit
from lensdual.inference import (
    SubhaloPopulation,
    abundance_posterior,
    apply_population,
    calibrate_posterior,
    composite_weight,
    simulate_anomalies,
)
from lensdual.simulation import noisy_constellation
from lensdual.simulation.families import calibration_system, clean_constellation

PRIOR = (1e-3, 0.3)  # kpc^-2


def run_family(family, args, out):
    system, info = calibration_system(family)
    pairs = clean_constellation(family, args.n_sources, seed=args.seed)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"], log_m_host=args.log_m_host,
                            los_normalization=args.los_normalization)
    grid = np.geomspace(*PRIOR, args.n_grid) / u.kpc**2
    t0 = time.perf_counter()
    with ThreadPoolExecutor(args.threads) as pool:
        sim = simulate_anomalies(pairs, system, pop, grid, n_realisations=args.n_real,
                                 seed=args.seed, client=pool)
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    weight = 1.0 if args.no_weight else composite_weight(
        pairs, system, sim, sigma_pos=args.sigma_pos_mas * u.mas, flux_rel_err=args.flux_rel_err,
        n_mocks=args.n_mocks, seed=args.seed + 7, test=args.test, snr_definition="log",
        anomaly=args.test)
    t_weight = time.perf_counter() - t0
    sigma_pos = args.sigma_pos_mas * u.mas
    t0 = time.perf_counter()
    calibration = None if args.n_calibration == 0 else calibrate_posterior(
        pairs, system, sim, sigma_pos=sigma_pos, flux_rel_err=args.flux_rel_err,
        n_mocks=args.n_calibration, seed=args.seed + 11, test=args.test, snr_definition="log",
        anomaly=args.test)
    t_calib = time.perf_counter() - t0
    rng = np.random.default_rng(args.seed + 1)
    weights = {"w=1": (1.0, None), f"w={weight:.3f}": (weight, None)}
    if calibration is not None:
        weights["calibrated"] = (1.0, calibration)
    rows = {key: [] for key in weights}
    t0 = time.perf_counter()
    for k in range(args.n_universes):
        truth = 10 ** rng.uniform(*np.log10(PRIOR))
        mock = apply_population(pairs, system, pop, truth / u.kpc**2, seed=10_000 + k)
        noisy = noisy_constellation(mock, sigma_pos=sigma_pos, flux_rel_err=args.flux_rel_err,
                                    seed=20_000 + k)
        result = check_duality(noisy, sigma_pos=sigma_pos, seed=k, test=args.test,
                               snr_definition="log")
        if args.oracle_noise:
            # the measured anomaly replaced by the truth plus independent noise of the
            # reported error: isolates the error model from the forward model
            err = result["duality_ratio_err"] / result["duality_ratio"]
            delta = np.asarray(mock["subhalo_delta"]) + rng.standard_normal(len(err)) * err
            result["duality_ratio"] = np.exp(delta)
            result["mu_flux"] = result["mu_size"] * np.exp(delta)
            result["duality_ratio_err"] = np.exp(delta) * err
        for key, (w, calib) in weights.items():
            m = abundance_posterior(result, sim, weights=w, anomaly=args.test,
                                    calibrations=calib).meta["inference"]
            lo68, hi68 = m["interval_68"].to_value(u.kpc**-2)
            lo95, hi95 = m["interval_95"].to_value(u.kpc**-2)
            if calib is not None:
                calibration_meta = m
            rows[key].append((truth, m["median"].to_value(u.kpc**-2), lo68 <= truth <= hi68,
                              lo95 <= truth <= hi95, np.log10(hi95 / lo95),
                              int(result["anomalous"].sum()), m["n_pairs"], truth < lo95))
    t_uni = time.perf_counter() - t0
    n_tested = int(np.median([row[6] for row in rows["w=1"]]))
    p_det = detection_probability_limit(n_tested, n_arcs=2, confidence=0.95)
    paper = surface_density_limit(p_det, 1e8 * u.Msun, z_lens=info["z_lens"],
                                  z_source=info["z_source"], zeta=3).to_value(u.kpc**-2)
    head = (f"{family}: {args.n_universes} universes, {args.n_sources} sources, "
            f"{args.sigma_pos_mas:g} mas, {100 * args.flux_rel_err:g} % flux, {args.test} test; "
            + (f"line-of-sight haloes x {args.los_normalization:g}; "
               if args.los_normalization else "")
            + f"forward model {args.n_real} x {args.n_grid}; composite weight from {args.n_mocks} "
            f"mocks; " + (f"calibrated on {args.n_calibration} mocks; " if calibration else "")
            + f"t_sim={t_sim:.0f}s t_weight={t_weight:.0f}s t_calibration={t_calib:.0f}s "
            f"t_universes={t_uni:.0f}s; "
            f"binomial bound of the same sources {paper:.3f} kpc^-2 (n_tested={n_tested})")
    print(head, flush=True)
    out.append(head)
    for key, rr in rows.items():
        r = np.array(rr, dtype=float)
        bias = np.log10(r[:, 1] / r[:, 0])
        n = len(r)
        cov68, cov95 = r[:, 2].mean(), r[:, 3].mean()
        line = (f"  {key:8s} cov68={cov68:.3f} (+-{np.sqrt(cov68 * (1 - cov68) / n):.3f}) "
                f"cov95={cov95:.3f} (+-{np.sqrt(cov95 * (1 - cov95) / n):.3f}) "
                f"below95={r[:, 7].mean():.3f} above95={max(0.0, 1 - cov95 - r[:, 7].mean()):.3f} "
                f"bias_median={np.median(bias):+.3f} bias_mean={np.mean(bias):+.3f} dex "
                f"width95={np.median(r[:, 4]):.2f} dex no_flag={(r[:, 5] == 0).mean():.2f}")
        print(line, flush=True)
        out.append(line)
        if key == "calibrated":
            mc = calibration_meta["mock_coverage_uncalibrated"]
            line = (f"      the calibration's mocks ({calibration_meta['n_mocks']} used): "
                    f"uncalibrated cov68={mc['68']:.3f} cov95={mc['95']:.3f}")
            print(line, flush=True)
            out.append(line)
        # the truth's position in the prior, binned: where coverage is lost
        for lo, hi in ((-3, -2), (-2, -1.5), (-1.5, -0.5)):
            sel = (np.log10(r[:, 0]) >= lo) & (np.log10(r[:, 0]) < hi)
            if sel.any():
                sub = (f"      log10 truth in [{lo}, {hi}): n={sel.sum():3d} "
                       f"cov68={r[sel, 2].mean():.2f} cov95={r[sel, 3].mean():.2f} "
                       f"bias_median={np.median(bias[sel]):+.3f} dex")
                print(sub, flush=True)
                out.append(sub)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--families", default="smacs_analog,macs1149_lenstool")
    p.add_argument("--n-universes", type=int, default=100)
    p.add_argument("--n-sources", type=int, default=20)
    p.add_argument("--n-real", type=int, default=1000)
    p.add_argument("--n-grid", type=int, default=30)
    p.add_argument("--sigma-pos-mas", type=float, default=10.0)
    p.add_argument("--flux-rel-err", type=float, default=0.02)
    p.add_argument("--log-m-host", type=float, default=15.0)
    p.add_argument("--los-normalization", type=float, default=0.0,
                   help="line-of-sight haloes (pyHalo's LOS_normalization) in the mocks and "
                        "the model")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default=None)
    p.add_argument("--n-mocks", type=int, default=100, help="mocks of the composite weight")
    p.add_argument("--n-calibration", type=int, default=300,
                   help="mocks of the posterior's calibration (0: none)")
    p.add_argument("--no-weight", action="store_true", help="weight 1 (independent errors)")
    p.add_argument("--oracle-noise", action="store_true",
                   help="replace each measured anomaly by the truth plus independent noise")
    p.add_argument("--test", choices=("geometric", "joint"), default="geometric",
                   help="the test of check_duality and of the composite weight's mocks")
    args = p.parse_args()
    if args.oracle_noise and args.test != "geometric":
        # the oracle replaces the geometric test's columns; the joint test's
        # posterior reads ln_mu_predicted, which it leaves alone
        p.error("--oracle-noise replaces the geometric test's anomalies: use --test geometric")
    use_shared_data()
    out = [f"# {vars(args)}"]
    for family in args.families.split(","):
        run_family(family, args, out)
    if args.out:
        with open(args.out, "w") as f:
            f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
