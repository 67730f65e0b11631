"""Forward models of many constellations on a dask LocalCluster, against a serial run.

Run on demand (not part of the test suite; it needs ``distributed``)::

    python benchmarks/bench_inference_dask.py [--n-systems 10] [--n-sources 20]
        [--n-real 1000] [--n-grid 30] [--workers 2] [--threads-per-worker 1]
        [--family smacs_analog]

``--n-systems`` clean constellations of ``--n-sources`` sources in one lens
family (seeds 0, 1, ...) are forward-modelled by
:func:`lensdual.inference.simulate_anomalies` (CDM at the family's redshifts,
``--n-real`` realisations on ``--n-grid`` abundances from 1e-3 to 0.3
kpc^-2), first serially, then with ``client=`` a ``distributed.Client`` on a
``LocalCluster`` of ``--workers`` processes. Each system's images are the
tasks; the systems are submitted one after the other, as
:func:`lensdual._inference_run.run_inference` does. The script asserts that
every system's anomalies are identical on the cluster and serially, and
prints the times: the serial total, the cluster's start, the cluster total,
and their ratio. The Numba kernels are compiled (or loaded from the cache),
and pyHalo imported, before any timing; each worker does the same before
the cluster is timed.
"""

import argparse
import time

import numpy as np
from _shared_data import use_shared_data
from astropy import units as u

from lensdual.inference import SubhaloPopulation, simulate_anomalies
from lensdual.simulation.families import calibration_system, clean_constellation

PRIOR = (1e-3, 0.3)  # kpc^-2


def _warm_up():
    """Compile (or load) the forward model's kernels and build pyHalo's tables."""
    system, info = calibration_system("smacs_analog")
    pairs = clean_constellation("smacs_analog", 8, seed=0)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    simulate_anomalies(pairs, system, pop, np.geomspace(*PRIOR, 2) / u.kpc**2,
                       n_realisations=100, seed=0)
    return True


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n-systems", type=int, default=10)
    p.add_argument("--n-sources", type=int, default=20)
    p.add_argument("--n-real", type=int, default=1000)
    p.add_argument("--n-grid", type=int, default=30)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--threads-per-worker", type=int, default=1)
    p.add_argument("--family", default="smacs_analog")
    args = p.parse_args()
    use_shared_data()
    import distributed

    system, info = calibration_system(args.family)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    grid = np.geomspace(*PRIOR, args.n_grid) / u.kpc**2
    systems = [clean_constellation(args.family, args.n_sources, seed=k)
               for k in range(args.n_systems)]
    _warm_up()

    def forward(client):
        return [simulate_anomalies(pairs, system, pop, grid, n_realisations=args.n_real,
                                   seed=k, client=client) for k, pairs in enumerate(systems)]

    t0 = time.perf_counter()
    serial = forward(None)
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    with distributed.LocalCluster(n_workers=args.workers,
                                  threads_per_worker=args.threads_per_worker, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        client.run(_warm_up)
        t_start = time.perf_counter() - t0
        t0 = time.perf_counter()
        on_dask = forward(client)
        t_dask = time.perf_counter() - t0
    for k, (a, b) in enumerate(zip(serial, on_dask, strict=True)):
        assert np.array_equal(a.delta, b.delta, equal_nan=True), f"system {k} differs"
        assert np.array_equal(a.excess1, b.excess1) and np.array_equal(a.excess2, b.excess2)
    n_images = 2 * sum(len(s) for s in systems)
    print(f"{args.n_systems} systems of {args.n_sources} sources ({args.family}), "
          f"{args.n_real} realisations x {args.n_grid} abundances, {n_images} image tasks")
    print(f"serial:        {t_serial:8.1f} s")
    print(f"LocalCluster:  {t_dask:8.1f} s  ({args.workers} workers x "
          f"{args.threads_per_worker} thread(s); start and warm-up {t_start:.1f} s)")
    print(f"speed-up:      {t_serial / t_dask:8.2f}")
    print("identical anomalies on the cluster and serially: yes (asserted)")


if __name__ == "__main__":
    main()
