"""How many constellations separate CDM from WDM with a half-mode mass of 1e8 Msun?

Run on demand (minutes)::

    python benchmarks/inference_wdm.py [--family smacs_analog] [--n-mocks 100]
        [--sigma-pos-mas 5,10,20] [--flux-rel-err 0.02] [--out FILE]

At pyHalo's default abundance (``sigma_sub`` = 0.025 kpc^-2), the forward
model of one 20-source constellation is run under CDM and under WDM
(``log_mhm`` = 8). Mock universes are drawn under each model, analysed by
``check_duality`` (the geometric test, linearised SNR), and their log-likelihood ratio
:math:`\\Delta = w(\\ell_{\\rm CDM} - \\ell_{\\rm WDM})` is recorded, with the
constellation's composite weight :math:`w`. With means :math:`m_C, m_W` and
standard deviations :math:`s_C, s_W` of :math:`\\Delta` under each model,
:math:`N` independent constellations separate the two at 95 % (one-sided,
either way) when :math:`N (m_C - m_W) \\ge 1.645 \\sqrt{N} (s_C + s_W)`,
i.e. :math:`N_{95} = [1.645 (s_C + s_W) / (m_C - m_W)]^2`.
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
    composite_weight,
    simulate_anomalies,
)
from lensdual.inference._posterior import _system_log_likelihood
from lensdual.simulation import noisy_constellation
from lensdual.simulation.families import calibration_system, clean_constellation

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

SIGMA_SUB = 0.025  # kpc^-2, pyHalo's default


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", default="smacs_analog")
    p.add_argument("--n-sources", type=int, default=20)
    p.add_argument("--n-real", type=int, default=1000)
    p.add_argument("--n-mocks", type=int, default=100)
    p.add_argument("--sigma-pos-mas", default="5,10,20")
    p.add_argument("--flux-rel-err", type=float, default=0.02)
    p.add_argument("--log-mhm", type=float, default=8.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default=None)
    args = p.parse_args()
    use_shared_data()
    system, info = calibration_system(args.family)
    pairs = clean_constellation(args.family, args.n_sources, seed=args.seed)
    models = {"CDM": SubhaloPopulation(info["z_lens"], info["z_source"]),
              "WDM": SubhaloPopulation(info["z_lens"], info["z_source"], model="WDM",
                                       log_mhm=args.log_mhm)}
    grid = np.array([SIGMA_SUB / 2, SIGMA_SUB]) / u.kpc**2
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        sims = {k: simulate_anomalies(pairs, system, pop, grid, n_realisations=args.n_real,
                                      seed=args.seed + i, client=pool)
                for i, (k, pop) in enumerate(models.items())}
    lines = [f"# {args.family}, {args.n_sources} sources, sigma_sub = {SIGMA_SUB} kpc^-2, "
             f"WDM log10 m_hm = {args.log_mhm}, {100 * args.flux_rel_err:g} % flux, "
             f"{args.n_mocks} mocks per model; forward models in "
             f"{time.perf_counter() - t0:.0f} s"]
    with ThreadPoolExecutor(2) as pool:
        # the composite weight needs the likelihood's slope and curvature: a CDM grid
        weight_sim = simulate_anomalies(pairs, system, models["CDM"],
                                        np.geomspace(1e-3, 0.3, 16) / u.kpc**2,
                                        n_realisations=300, seed=args.seed + 5, client=pool)
    spread = {k: float(np.std(s.delta[:, :, -1])) for k, s in sims.items()}
    lines.append("# spread of the simulated anomalies ln(f1/f2): "
                 + ", ".join(f"{k} {v:.4f}" for k, v in spread.items()))
    rng = np.random.default_rng(args.seed + 2)
    for mas in [float(v) for v in args.sigma_pos_mas.split(",")]:
        sigma_pos = mas * u.mas
        w = composite_weight(pairs, system, weight_sim, sigma_pos=sigma_pos,
                             flux_rel_err=args.flux_rel_err, n_mocks=50,
                             seed=int(rng.integers(2**31)), **GEOMETRIC)
        stats = {}
        for name, pop in models.items():
            d = []
            for _ in range(args.n_mocks):
                mock = apply_population(pairs, system, pop, SIGMA_SUB / u.kpc**2,
                                        seed=int(rng.integers(2**31)))
                noisy = noisy_constellation(mock, sigma_pos=sigma_pos,
                                            flux_rel_err=args.flux_rel_err,
                                            seed=int(rng.integers(2**31)))
                result = check_duality(noisy, sigma_pos=sigma_pos,
                                       seed=int(rng.integers(2**31)), **GEOMETRIC)
                ll = {k: _system_log_likelihood(result, s)[0][-1] for k, s in sims.items()}
                d.append(w * (ll["CDM"] - ll["WDM"]))
            stats[name] = (np.mean(d), np.std(d, ddof=1))
        (mc, sc), (mw, sw) = stats["CDM"], stats["WDM"]
        n95 = (1.645 * (sc + sw) / (mc - mw)) ** 2 if mc > mw else np.inf
        line = (f"sigma_pos {mas:4.0f} mas: weight {w:.3f}; Delta under CDM {mc:+.3f} +- {sc:.3f}, "
                f"under WDM {mw:+.3f} +- {sw:.3f}; N_95 = {n95:.0f} constellations")
        print(line, flush=True)
        lines.append(line)
    print("\n".join(lines[:2]))
    if args.out:
        with open(args.out, "w") as f:
            f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
