"""Speed of ``size_magnification`` against the plain-numpy reference.

Run on demand (not part of the test suite)::

    python benchmarks/bench_estimators.py [--n-pairs 30] [--n-bootstrap 1000] [--output FILE]

Both paths do the same work in the same process: the relative Jacobian of
every pair on the measured positions, then ``n_bootstrap`` realisations of
Gaussian positional noise on both arcs, each re-estimated. The reference is
``tests/_reference.py`` (one ``numpy.linalg.lstsq`` per pair). Compilation is
timed separately, in fresh interpreters: once with an empty Numba cache
(cold) and once with the cache that run wrote (warm).
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy import units as u

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import _reference as ref  # noqa: E402
from _output import Record, add_output_argument  # noqa: E402

from lensdual.estimators import size_magnification  # noqa: E402

FIRST_CALL = """
import time, numpy as np, astropy.units as u
t = np.random.default_rng(0).normal(size=(30, 2))
start = time.perf_counter()
from lensdual.estimators import size_magnification
for m in {methods!r}:
    size_magnification((t @ [[1.2, 0.3], [0.1, -0.8]]) * u.arcsec, t * u.arcsec, m,
                       n_bootstrap=10, seed=0)
print(time.perf_counter() - start)
"""


def constellation(n, seed=0):
    rng = np.random.default_rng(seed)
    t2 = rng.normal(scale=0.5, size=(n, 2))
    x, y = t2.T
    t1 = np.column_stack([1.3 * x - 0.4 * y + 0.05 * x * y, -0.3 * x - 0.9 * y + 0.04 * x**2])
    return t1, t2


def best_of(func, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def first_call_seconds(methods):
    """Import + first calls in a fresh interpreter: (cold cache, warm cache)."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        code = FIRST_CALL.format(methods=methods)
        out = []
        for _ in range(2):
            res = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                                 capture_output=True, text=True)
            out.append(float(res.stdout.split()[-1]))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-pairs", type=int, default=30)
    parser.add_argument("--n-bootstrap", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=5)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()

    t1, t2 = constellation(args.n_pairs)
    sigma = 0.06
    rows = []
    for method in ("quad", "2v", "quad2"):
        def fast(method=method):
            return size_magnification(t1 * u.arcsec, t2 * u.arcsec, method,
                                      sigma_pos=sigma * u.arcsec,
                                      n_bootstrap=args.n_bootstrap, seed=1)

        def slow(method=method):
            return ref.size_magnification(t1, t2, sigma, args.n_bootstrap,
                                          np.random.default_rng(1), method)

        tab = fast()  # compile (or load from cache) before timing
        mu, err, _ = slow()
        np.testing.assert_allclose(tab["mu_size"], mu, rtol=1e-8)
        np.testing.assert_allclose(tab["mu_size_err"], err, rtol=1e-6)
        t_fast = best_of(fast, args.repeat)
        t_slow = best_of(slow, max(1, args.repeat // 3))
        rows.append((method, t_fast, t_slow, t_slow / t_fast))

    first = {m: first_call_seconds(m) for m in (("quad",), ("quad", "2v", "quad2"))}
    rec.say(f"size_magnification, N = {args.n_pairs} pairs, n_bootstrap = {args.n_bootstrap}")
    rec.say(f"{'method':<8}{'numba [ms]':>12}{'numpy ref [ms]':>16}{'speed-up':>10}")
    for method, t_fast, t_slow, ratio in rows:
        rec.say(f"{method:<8}{1e3 * t_fast:>12.1f}{1e3 * t_slow:>16.0f}{ratio:>9.0f}x")
    for methods, (cold, warm) in first.items():
        rec.say(f"import + first call of {', '.join(methods)}: {cold:.1f} s with an empty Numba "
                f"cache, {warm:.1f} s with a warm cache")
    rec.write(args.output)
    return rows


if __name__ == "__main__":
    main()
