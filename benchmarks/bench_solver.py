"""Speed of ``ImageFinder`` against lenstronomy's ``LensEquationSolver``.

Run on demand (not part of the test suite)::

    python benchmarks/bench_solver.py [--n-sources 30] [--n-lenstronomy 4]
                                     [--output FILE]

The lens is an elliptical NFW cluster halo (``NFW_ELLIPSE_CSE``, 5e14 Msun,
c = 4, e1 = 0.1, e2 = 0.05, z = 0.39 / 2.2). ``n_sources`` point sources are
drawn just inside a fold of the tangential caustic (image pairs with |mu| ~
10-1000). Both methods search the same 100" x 100" field at settings that find
every image and stop at the same source-plane precision (1e-10"):

* lenstronomy: ``image_position_from_source(search_window=100, min_distance=0.05,
  precision_limit=1e-10, num_iter_max=100)``, one call per source, timed on the
  first ``n_lenstronomy`` sources only (it takes seconds per call);
* ImageFinder, twice: with its default grid (0.1" everywhere, refined 4x near
  critical curves) and with a coarse grid (0.5", refined 5x, i.e. 0.1", near
  critical curves); both refine strongly non-linear cells and the lens centre
  recursively (3 levels). The grid is built once;
  all sources are solved in one ``solve`` call. Reported per source: the solve
  alone, and build + solve divided by the number of sources (amortised).

The Numba kernels are compiled (or loaded from the cache) before timing.
"""

import argparse
import time

import numpy as np
from _output import Record, add_output_argument
from astropy.cosmology import FlatLambdaCDM
from lenstronomy.Cosmo.lens_cosmo import LensCosmo
from lenstronomy.LensModel.lens_model import LensModel
from lenstronomy.LensModel.Solver.lens_equation_solver import LensEquationSolver

from lensdual._lens._solver import ImageFinder

PRECISION = 1e-10
SEARCH_WINDOW = 100.0
MIN_DISTANCE = 0.05


def cluster_lens():
    lens_cosmo = LensCosmo(z_lens=0.39, z_source=2.2, cosmo=FlatLambdaCDM(H0=70, Om0=0.3))
    rs, alpha_rs = lens_cosmo.nfw_physical2angle(M=5e14, c=4)
    kwargs = [{"Rs": rs, "alpha_Rs": alpha_rs, "e1": 0.1, "e2": 0.05,
               "center_x": 0.0, "center_y": 0.0}]
    return LensModel(["NFW_ELLIPSE_CSE"]), kwargs


def tangential_caustic(model, kwargs, r_in=3.0, r_out=12.0, n=720):
    """Exact samples of the tangential critical curve (bisection of det A along rays)."""
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(phi), np.sin(phi)

    def det(r):
        fxx, fxy, fyx, fyy = model.hessian(r * c, r * s, kwargs)
        return (1 - fxx) * (1 - fyy) - fxy * fyx

    lo, hi = np.full(n, r_in), np.full(n, r_out)
    if not ((det(lo) < 0).all() and (det(hi) > 0).all()):
        raise RuntimeError("the tangential critical curve is not bracketed")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        neg = det(mid) < 0
        lo, hi = np.where(neg, mid, lo), np.where(neg, hi, mid)
    r = 0.5 * (lo + hi)
    bx, by = model.ray_shooting(r * c, r * s, kwargs)
    return np.column_stack([bx, by])


def fold_sources(model, kwargs, n, seed=0):
    """Sources just inside the tangential caustic, around its fold closest to the centre."""
    caustic = tangential_caustic(model, kwargs)
    k0 = int(np.argmin(np.hypot(*caustic.T)))
    rng = np.random.default_rng(seed)
    k = (k0 + rng.integers(-8, 9, n)) % len(caustic)
    depth = 10 ** rng.uniform(-4, -2, n)  # fractional distance inside the caustic
    return caustic[k] * (1 - depth)[:, None]


def time_finder(model, kwargs, beta, **settings):
    start = time.perf_counter()
    finder = ImageFinder(model, kwargs, half_width=SEARCH_WINDOW / 2, precision=PRECISION,
                         **settings)
    build = time.perf_counter() - start
    solves = []
    for _ in range(3):
        start = time.perf_counter()
        out = finder.solve(beta)
        solves.append(time.perf_counter() - start)
    return finder, out, build, min(solves)


def time_lenstronomy(model, kwargs, beta):
    solver = LensEquationSolver(model)
    images = []
    start = time.perf_counter()
    for bx, by in beta:
        x, y = solver.image_position_from_source(
            bx, by, kwargs, search_window=SEARCH_WINDOW, min_distance=MIN_DISTANCE,
            precision_limit=PRECISION, num_iter_max=100)
        images.append(np.column_stack([x, y]).reshape(-1, 2))
    return images, (time.perf_counter() - start) / len(beta)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n-sources", type=int, default=30)
    parser.add_argument("--n-lenstronomy", type=int, default=4)
    add_output_argument(parser)
    args = parser.parse_args()
    rec = Record()

    model, kwargs = cluster_lens()
    beta = fold_sources(model, kwargs, args.n_sources)
    # compile / load the Numba kernels outside the timings
    ImageFinder(model, kwargs, half_width=5.0, grid_spacing=1.0).solve(beta[:1])

    configs = {
        "ImageFinder default (0.1\", refine 4)": {"grid_spacing": 0.1, "refine": 4},
        "ImageFinder coarse (0.5\", refine 5)": {"grid_spacing": 0.5, "refine": 5},
    }
    results = {name: time_finder(model, kwargs, beta, **cfg) for name, cfg in configs.items()}
    m = min(args.n_lenstronomy, args.n_sources)
    lt_images, lt_time = time_lenstronomy(model, kwargs, beta[:m])
    lt_counts = [len(t) for t in lt_images]

    n = args.n_sources
    rec.say(f"NFW_ELLIPSE_CSE cluster, {n} sources inside a fold of the tangential caustic; "
            f"field {SEARCH_WINDOW:g}\", precision {PRECISION:g}\"")
    rec.say(f"lenstronomy LensEquationSolver (search_window={SEARCH_WINDOW:g}, "
            f"min_distance={MIN_DISTANCE:g}), timed on {m} sources: {lt_time:.3f} s per source")
    header = (f"{'method':40s} {'points':>8s} {'build s':>8s} {'solve s':>8s} "
              f"{'s/source':>9s} {'ratio':>7s} {'amort. s/src':>12s} {'ratio':>7s}")
    rec.say(header)
    rec.say("-" * len(header))
    rec.say(f"{'lenstronomy (per call)':40s} {'':>8s} {'':>8s} {'':>8s} {lt_time:9.4f} "
            f"{1.0:7.1f} {lt_time:12.4f} {1.0:7.1f}")
    for name, (finder, _, build, solve) in results.items():
        per = solve / n
        amortised = (build + solve) / n
        rec.say(f"{name:40s} {finder.n_points:8d} {build:8.3f} {solve:8.4f} {per:9.5f} "
                f"{lt_time / per:7.0f} {amortised:12.5f} {lt_time / amortised:7.0f}")

    rec.say("images found per source:")
    for name, (_, out, _, _) in results.items():
        counts = np.bincount(out["source"], minlength=n)
        values, times = np.unique(counts, return_counts=True)
        histogram = dict(zip(values.tolist(), times.tolist(), strict=True))
        rec.say(f"  {name:40s} total {counts.sum():4d}  histogram {histogram}")
    rec.say(f"  lenstronomy (first {m} sources): {lt_counts}")
    for name, (_, out, _, _) in results.items():
        ours = [out["theta"][out["source"] == s] for s in range(m)]
        common = sum(
            sum(len(o) > 0 and np.hypot(*(o - t).T).min() < 1e-6 for t in theirs)
            for o, theirs in zip(ours, lt_images, strict=True))
        rec.say(f"  {name:40s} on those: {[len(o) for o in ours]}, "
                f"{common} of lenstronomy's {sum(lt_counts)} images matched within 1e-6\"")
    mu = np.abs(results[next(iter(results))][1]["magnification"])
    rec.say(f"  |mu| range of the images: {mu.min():.3g} - {mu.max():.3g}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
