"""Speed of the sub-halo detection-SNR map (paper Fig. 9), serial, on 2 workers, and lenstronomy.

Run on demand (not part of the test suite)::

    python benchmarks/bench_sensitivity.py [--n-lenstronomy 60] [--workers 2] [--repeat 3]
                                           [--no-dask] [--output FILE]

The map: 20 masses (1e7-1e10 Msun) x 24 r_eff (0.125-3) x 36 angles x 2
concentration models (the mass-concentration relation and 5 times it) =
34,560 sub-halo placements on the L2 image of the SMACS0723 analogue, with
:func:`lensdual.sensitivity.detection_snr_map` (Numba kernels, a local linear
macro model, one image-search grid per mass). Timed:

* serially, in this process (after a small warm-up map that loads the
  compiled kernels from Numba's cache);
* on a ``concurrent.futures.ThreadPoolExecutor`` with ``--workers`` threads
  (the kernels release the GIL);
* on a ``dask.distributed.LocalCluster`` of ``--workers`` single-threaded
  worker processes (warmed up the same way; start-up not timed), chunks of
  one mass. All three must give identical tables.

Each is timed ``--repeat`` times and the best time is reported (the
machine may be shared).

The reference: the same placement computed with lenstronomy, for
``--n-lenstronomy`` placements drawn at random from the map: the full macro
model (``NFW_ELLIPSE_CSE``) plus the ``TNFW`` sub-halo in one ``LensModel``,
``LensEquationSolver.image_position_from_source`` on the same search grid as
lensdual's (a box of half-width ``10 theta_E / sqrt(min |lambda|)`` around
the sub-halo, 400 cells a side: ``search_window = 2 h``, ``min_distance =
2 h / 400``, ``precision_limit = 1e-10``), and ``LensModel.magnification``
of the images found; the flux excess is their ``sum |mu|`` over the macro
``|mu|``. Images closer to the analogue's L1 image than to the L2 image
(which the widest boxes, for M > 3e9 Msun, reach) are left out: the local
model has no L1. Reported: seconds per placement for each, the speed-up,
how often the image counts agree, and how well the two flux excesses agree
where they do (the local model neglects the variation of the macro field
across the box, which shows for the heaviest sub-haloes).
"""

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import astropy.units as u
import numpy as np
from _output import Record, add_output_argument
from lenstronomy.LensModel.lens_model import LensModel
from lenstronomy.LensModel.Solver.lens_equation_solver import LensEquationSolver

from lensdual.abundance import einstein_radius
from lensdual.sensitivity import (
    detection_snr_map,
    flux_excess,
    offsets_on_ellipse,
    subhalo_einstein_radius,
)
from lensdual.simulation.halos import mass_concentration, tnfw_halo
from lensdual.simulation.scenarios import smacs0723_analog

MASSES = np.geomspace(1e7, 1e10, 20) * u.Msun
R_EFF = np.arange(1, 25) * 0.125
N_ANGLES = 36
MODELS = ("mcr", 5.0)
N_GRID = 400
BOX = 10.0


def lensdual_map(jacobian, **kw):
    return [detection_snr_map(MASSES, R_EFF, jacobian=jacobian, sigma_rel=0.1, concentration=c,
                              n_angles=N_ANGLES, n_grid=N_GRID, box=BOX, **kw) for c in MODELS]


def timed(fn, *args, repeat=1, **kw):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        best = min(best, time.perf_counter() - t0)
    return out, best


def same(maps_a, maps_b):
    return all(np.array_equal(np.asarray(a[c]), np.asarray(b[c]))
               for a, b in zip(maps_a, maps_b, strict=True) for c in a.colnames)


def lenstronomy_sample(system, theta0, theta_l1, jacobian, n, seed=0):
    """Flux excess of ``n`` random placements, lenstronomy vs lensdual."""
    rng = np.random.default_rng(seed)
    beta0 = system.ray_shoot(theta0[None, :])[0].to_value(u.arcsec)
    t0 = theta0.to_value(u.arcsec)
    t1 = theta_l1.to_value(u.arcsec)
    profiles = [c.profile for c in system.components]
    model = LensModel(profiles + ["TNFW"])
    solver = LensEquationSolver(model)
    mu0 = abs(float(system.magnification(theta0[None, :])[0]))
    lam_min = np.abs(np.linalg.eigvalsh(jacobian)).min()
    rows = []
    t_lenstronomy = 0.0
    for _ in range(n):
        m = MASSES[rng.integers(MASSES.size)]
        model_c = MODELS[rng.integers(len(MODELS))]
        c = mass_concentration(m) * (1.0 if model_c == "mcr" else model_c)
        r = R_EFF[rng.integers(R_EFF.size)]
        ang = rng.integers(N_ANGLES) * (360.0 / N_ANGLES) * u.deg
        te = einstein_radius(m, 0.39, 2.2)
        d = offsets_on_ellipse([r], ang, jacobian, te)
        sub = tnfw_halo(m, c, z_lens=0.39, z_source=2.2)
        fe, cnt = flux_excess(jacobian, sub, d, return_counts=True, n_grid=N_GRID, box=BOX)
        h = BOX * subhalo_einstein_radius(sub).value / np.sqrt(lam_min)
        centre = t0 + d.value[0]
        kw = system.kwargs_lens + [dict(sub.kwargs, center_x=centre[0], center_y=centre[1])]
        start = time.perf_counter()
        x, y = solver.image_position_from_source(
            beta0[0], beta0[1], kw, search_window=2 * h, min_distance=2 * h / N_GRID,
            precision_limit=1e-10, num_iter_max=100, x_center=centre[0], y_center=centre[1])
        mu = model.magnification(x, y, kw) if len(x) else np.array([])
        t_lenstronomy += time.perf_counter() - start
        xy = np.column_stack([x, y]) if len(x) else np.empty((0, 2))
        keep = np.hypot(*(xy - t0).T) < np.hypot(*(xy - t1).T)
        rows.append((m.value, c, r, fe[0], cnt[0], np.abs(mu[keep]).sum() / mu0, keep.sum()))
    return np.array(rows), t_lenstronomy / n


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-lenstronomy", type=int, default=60)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-dask", action="store_true")
    add_output_argument(parser)
    args = parser.parse_args()
    rec = Record()

    system = smacs0723_analog(seed=0)
    pairs = system.constellation()
    theta0 = u.Quantity([pairs["x2"][0], pairs["y2"][0]])
    theta_l1 = u.Quantity([pairs["x1"][0], pairs["y1"][0]])
    jacobian = system.jacobian(theta0[None, :])[0]
    n_place = MASSES.size * R_EFF.size * N_ANGLES * len(MODELS)
    rec.say(f"map: {MASSES.size} masses x {R_EFF.size} r_eff x {N_ANGLES} angles x "
            f"{len(MODELS)} concentration models = {n_place} placements")

    detection_snr_map(MASSES[:2], R_EFF[:2], jacobian=jacobian, sigma_rel=0.1, n_angles=2)
    serial, t_serial = timed(lensdual_map, jacobian, repeat=args.repeat)
    per = t_serial / n_place
    rec.say(f"lensdual serial:           {t_serial:7.2f} s  ({1e6 * per:.0f} us per placement)")
    with ThreadPoolExecutor(args.workers) as ex:
        threads, t_threads = timed(lensdual_map, jacobian, repeat=args.repeat, executor=ex)
    rec.say(f"lensdual, {args.workers} threads:       {t_threads:7.2f} s  "
            f"(speed-up {t_serial / t_threads:.2f}, identical: {same(serial, threads)})")
    if not args.no_dask:
        from distributed import Client, LocalCluster

        t_start = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            detection_snr_map(MASSES[:args.workers], R_EFF[:2], jacobian=jacobian,
                              sigma_rel=0.1, n_angles=2, client=client)  # warm the workers
            t_up = time.perf_counter() - t_start
            dask_maps, t_dask = timed(lensdual_map, jacobian, repeat=args.repeat,
                                      client=client)
        rec.say(f"lensdual, dask {args.workers} workers:  {t_dask:7.2f} s  "
                f"(speed-up {t_serial / t_dask:.2f}, identical: {same(serial, dask_maps)}; "
                f"cluster start + warm-up {t_up:.1f} s, not timed)")

    rows, per_lt = lenstronomy_sample(system, theta0, theta_l1, jacobian, args.n_lenstronomy)
    rec.say(f"lenstronomy, {args.n_lenstronomy} random placements: {per_lt:.3f} s per placement "
            f"-> {per_lt * n_place / 3600:.1f} h for the map")
    rec.say(f"speed-up per placement (serial lensdual): {per_lt / per:.0f}x")
    mass, fe, n_ld, fe_lt, n_lt = rows[:, 0], rows[:, 3], rows[:, 4], rows[:, 5], rows[:, 6]
    same_n = n_ld == n_lt
    rec.say(f"image counts: equal in {same_n.sum()} of {len(rows)}; lenstronomy found fewer in "
            f"{(n_lt < n_ld).sum()}, lensdual fewer in {(n_ld < n_lt).sum()}")
    rel = np.abs(fe_lt / fe - 1)
    light = mass <= 1.01e9
    for name, sel in (("M <= 1e9", same_n & light), ("M > 1e9", same_n & ~light)):
        if sel.any():
            rec.say(f"  |f_lenstronomy / f_lensdual - 1|, {name} ({sel.sum()}): median "
                    f"{np.median(rel[sel]):.1e}, max {rel[sel].max():.1e}")
    for row in rows[np.argsort(-np.where(same_n, rel, -1.0))[:3]]:
        rec.say(f"  M = {row[0]:.2e}, c = {row[1]:6.1f}, r_eff = {row[2]:.3f}: "
                f"lensdual f = {row[3]:.5f} ({row[4]:.0f} images), "
                f"lenstronomy f = {row[5]:.5f} ({row[6]:.0f} images)")
    rec.write(args.output)


if __name__ == "__main__":
    main()
