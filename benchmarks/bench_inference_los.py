"""The forward model's cost with line-of-sight haloes, against the same model without.

Run on demand::

    python benchmarks/bench_inference_los.py [--family smacs_analog] [--n-sources 20]
        [--n-real 1000] [--n-grid 30] [--threads 2] [--los-normalization 1]

One clean constellation of ``--n-sources`` sources in the family's lens is
forward-modelled by :func:`lensdual.inference.simulate_anomalies` (CDM at
the family's redshifts, ``--n-real`` realisations on ``--n-grid`` abundances
from 1e-3 to 0.3 kpc^-2, a thread pool of ``--threads``), first without,
then with line-of-sight haloes (pyHalo's ``LOS_normalization``), in the same
process after a warm-up that compiles the kernels. Printed: the population's
construction time, each forward model's time, their ratio, the line-of-sight
haloes per image and realisation, and the anomalies' spread at the lowest
and the highest abundance with and without them.
"""

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u

from lensdual.inference import SubhaloPopulation, simulate_anomalies
from lensdual.simulation.families import calibration_system, clean_constellation

PRIOR = (1e-3, 0.3)  # kpc^-2


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", default="smacs_analog")
    p.add_argument("--n-sources", type=int, default=20)
    p.add_argument("--n-real", type=int, default=1000)
    p.add_argument("--n-grid", type=int, default=30)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--los-normalization", type=float, default=1.0)
    args = p.parse_args()
    use_shared_data()
    system, info = calibration_system(args.family)
    pairs = clean_constellation(args.family, args.n_sources, seed=0)
    zl, zs = info["z_lens"], info["z_source"]
    grid = np.geomspace(*PRIOR, args.n_grid) / u.kpc**2
    t0 = time.perf_counter()
    plain = SubhaloPopulation(zl, zs)
    t_plain_pop = time.perf_counter() - t0
    t0 = time.perf_counter()
    los = SubhaloPopulation(zl, zs, los_normalization=args.los_normalization)
    t_los_pop = time.perf_counter() - t0
    for pop in (plain, los):  # compile the kernels
        simulate_anomalies(pairs[:4], system, pop, grid[:2], n_realisations=100, seed=0)
    times, sims = {}, {}
    with ThreadPoolExecutor(args.threads) as pool:
        for name, pop in (("without", plain), ("with", los)):
            t0 = time.perf_counter()
            sims[name] = simulate_anomalies(pairs, system, pop, grid,
                                            n_realisations=args.n_real, seed=1, client=pool)
            times[name] = time.perf_counter() - t0
    radius = sims["with"].radius
    per_image = [float(np.sum(los._los["density"])) * np.pi * r**2 for r in radius]
    print(f"{args.family}: {len(pairs)} pairs, {args.n_real} realisations x {args.n_grid} "
          f"abundances, {args.threads} threads, LOS_normalization {args.los_normalization:g}")
    print(f"  population: {t_plain_pop:.1f} s without, {t_los_pop:.1f} s with line-of-sight "
          f"haloes ({los._los['z'].size} planes)")
    print("  line-of-sight haloes per image and realisation: "
          + ", ".join(f"{n:.0f} (radius {r:.3f} arcsec)" for n, r in
                      zip(per_image, radius, strict=True)))
    print(f"  forward model: {times['without']:.1f} s without, {times['with']:.1f} s with: "
          f"ratio {times['with'] / times['without']:.2f}")
    for name, sim in sims.items():
        sd = np.std(sim.delta, axis=(0, 1))
        print(f"  sd of ln(f1/f2) {name:7s}: {sd[0]:.4f} at {grid[0].value:g} kpc^-2, "
              f"{sd[-1]:.4f} at {grid[-1].value:g} kpc^-2")


if __name__ == "__main__":
    main()
