"""The half-mode mass example of docs/inference.rst: ten SMACS0723-analogue constellations.

Run from the repository root (a few minutes on two cores)::

    python docs/scripts/half_mode_figure.py

The forward model of one 20-source constellation is run for WDM populations on
a grid of half-mode masses; ten mock universes of that constellation (each its
own population draw and noise) are drawn under cold dark matter and ten under
WDM with a half-mode mass of 1e9 Msun, at one abundance, analysed by
``check_duality`` and combined by :func:`~lensdual.inference.half_mode_posterior`
with the constellation's composite weight. Writes
``docs/_static/inference/half_mode.png`` (the CDM universes' posterior),
and ``half_mode.txt`` (the settings and both posteriors' summaries), which
``docs/scripts/inference_numbers.py`` reads the page's numbers from.
"""

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import matplotlib

matplotlib.use("agg")
import numpy as np  # noqa: E402
from astropy import units as u  # noqa: E402

from lensdual import check_duality  # noqa: E402
from lensdual.inference import (  # noqa: E402
    SubhaloPopulation,
    apply_population,
    composite_weight,
    half_mode_posterior,
    simulate_anomalies,
)
from lensdual.simulation import noisy_constellation  # noqa: E402
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402
from lensdual.visualization import plot_half_mode_posterior  # noqa: E402

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

OUT = Path(__file__).resolve().parents[1] / "_static" / "inference"
FAMILY = "smacs_analog"
LOG_MHM = (5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
TRUTH_SIGMA = 0.1  # kpc^-2
TRUTH_WDM = 9.0
N_SYSTEMS = 10
N_REAL = 500
N_GRID = 15
SIGMA_POS = 10 * u.mas
FLUX_ERR = 0.02


def summary(post):
    """One line: the abundance's median and 95 % interval, the half-mode mass's
    median, 95 % interval and upper limit."""
    m = post.meta["inference"]
    lo, hi = m["interval_95"].to_value(u.kpc**-2)
    mlo, mhi = m["log10_mhm_interval_95"]
    return (f"sigma_sub median {m['median'].to_value(u.kpc**-2):.4f}, 95 % [{lo:.4f}, "
            f"{hi:.4f}] kpc^-2; log10 m_hm median {m['log10_mhm_median']:.2f}, 95 % "
            f"[{mlo:.2f}, {mhi:.2f}], upper 95 % {m['log10_mhm_upper_95']:.2f}; "
            f"{m['n_pairs']} pairs in {m['n_systems']} constellations")


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    system, info = calibration_system(FAMILY)
    pairs = clean_constellation(FAMILY, 20, seed=1)
    zl, zs = info["z_lens"], info["z_source"]
    grid = np.geomspace(1e-3, 0.3, N_GRID) / u.kpc**2
    pops = {m: SubhaloPopulation(zl, zs, model="WDM", log_mhm=m) for m in LOG_MHM}
    with ThreadPoolExecutor(2) as pool:
        sims = {m: simulate_anomalies(pairs, system, pop, grid, n_realisations=N_REAL, seed=1,
                                      client=pool) for m, pop in pops.items()}
    weight = composite_weight(pairs, system, sims[LOG_MHM[0]], sigma_pos=SIGMA_POS,
                              flux_rel_err=FLUX_ERR, n_mocks=100, seed=2, **GEOMETRIC)
    truths = {"CDM": SubhaloPopulation(zl, zs),
              f"WDM log10 m_hm = {TRUTH_WDM:g}": SubhaloPopulation(zl, zs, model="WDM",
                                                                   log_mhm=TRUTH_WDM)}
    lines = [f"# {FAMILY}: 20 sources, {SIGMA_POS.value:g} mas, {100 * FLUX_ERR:g} % flux "
             f"errors; WDM forward models at log10 m_hm = {', '.join(f'{m:g}' for m in LOG_MHM)}"
             f", {N_REAL} realisations x {N_GRID} abundances; composite weight {weight:.3f} "
             f"(of the lightest); {N_SYSTEMS} mock constellations per truth, sigma_sub = "
             f"{TRUTH_SIGMA:g} kpc^-2"]
    for k, (name, pop) in enumerate(truths.items()):
        tables = []
        for j in range(N_SYSTEMS):
            mock = apply_population(pairs, system, pop, TRUTH_SIGMA / u.kpc**2,
                                    seed=700 + 100 * k + j)
            noisy = noisy_constellation(mock, sigma_pos=SIGMA_POS, flux_rel_err=FLUX_ERR,
                                        seed=900 + 100 * k + j)
            tables.append(check_duality(noisy, sigma_pos=SIGMA_POS, seed=j, **GEOMETRIC))
        slices = [[sims[m]] * N_SYSTEMS for m in LOG_MHM]
        post = half_mode_posterior(tables, slices, weights=[weight] * N_SYSTEMS)
        flagged = sum(int(t["anomalous"].sum()) for t in tables)
        lines.append(f"truth {name}: {summary(post)}; {flagged} pairs flagged")
        if k == 0:
            fig = plot_half_mode_posterior(post)
            fig.suptitle(f"{N_SYSTEMS} SMACS0723-analogue constellations, CDM at sigma_sub = "
                         f"{TRUTH_SIGMA:g} kpc$^{{-2}}$", fontsize=9)
            fig.tight_layout()
            fig.savefig(OUT / "half_mode.png", dpi=110)
    (OUT / "half_mode.txt").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
