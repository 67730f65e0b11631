"""Scale of ``size_magnification``: the neighbour cap against the uncapped estimators.

Run on demand (not part of the test suite)::

    python benchmarks/bench_scale_estimators.py [--sizes 1000 10000 100000]
        [--uncapped-max 10000] [--adaptive-uncapped-max 300] [--output FILE]

On a smooth, mildly curved map with 5 mas position noise and a constant
density of pairs (the field grows with N), each method is timed with the
default cap (``max_neighbours=64``) and, up to the given sizes, without a
cap (``max_neighbours=None``: every pair uses every point, the estimators
as they were before the cap) in the same process; the ratio is the speed-up.
``n_bootstrap=1`` for the bootstrap methods (the bootstrap costs one more
estimate per realisation). Also printed: the median and largest relative
difference of ``mu_size`` between the two.
"""

import argparse
import time
import warnings

import numpy as np
from _output import Record, add_output_argument
from astropy import units as u

from lensdual.estimators import size_magnification

SIGMA = 0.005


def constellation(n, seed=0):
    rng = np.random.default_rng(seed)
    sc = np.sqrt(n / 30)
    t2 = rng.uniform(-1, 1, (n, 2)) * sc
    x, y = t2.T / sc
    t1 = np.column_stack([1.3 * x - 0.4 * y + 0.05 * x * y + 0.1 * np.sin(2 * x),
                          -0.3 * x - 0.9 * y + 0.04 * x**2]) * sc
    return (t1 + SIGMA * rng.standard_normal(t1.shape),
            t2 + SIGMA * rng.standard_normal(t2.shape))


def timed(t1, t2, method, cap):
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, method,
                                 sigma_pos=SIGMA * u.arcsec, n_bootstrap=1, seed=0,
                                 max_neighbours=cap)
    return time.perf_counter() - start, tab


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--methods", nargs="+", default=["adaptive", "quad", "2v", "quad2"])
    parser.add_argument("--uncapped-max", type=int, default=10000)
    parser.add_argument("--adaptive-uncapped-max", type=int, default=300)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    t1, t2 = constellation(100)
    for m in args.methods:  # compile
        timed(t1, t2, m, 64)
        timed(t1, t2, m, None)
    rec.say(f"{'N':>7} {'method':>8} {'capped [s]':>10} {'uncapped [s]':>12} {'speed-up':>8} "
            f"{'median, max |dmu|/mu':>22}")
    for n in args.sizes:
        t1, t2 = constellation(n)
        for m in args.methods:
            tc, cap = timed(t1, t2, m, 64)
            limit = args.adaptive_uncapped_max if m == "adaptive" else args.uncapped_max
            if n <= limit:
                tu, full = timed(t1, t2, m, None)
                rel = np.abs(np.asarray(cap["mu_size"]) / np.asarray(full["mu_size"]) - 1)
                ratio = f"{tu / tc:8.1f}"
                diff = f"{np.nanmedian(rel):11.2g} {np.nanmax(rel):10.2g}"
                tu = f"{tu:12.3f}"
            else:
                tu, ratio, diff = f"{'--':>12}", f"{'--':>8}", f"{'--':>22}"
            rec.say(f"{n:7d} {m:>8} {tc:10.3f} {tu} {ratio} {diff}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
