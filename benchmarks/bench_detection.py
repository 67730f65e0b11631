"""Speed of the point-source filter against the Gaussian blurs it needs.

Run on demand (not part of the test suite)::

    python benchmarks/bench_detection.py [--size 4096] [--repeat 5]

Two bands of ``size x size`` pixels (a bright arc, ~800 point sources, noise).
Timed in the same process (wall clock), each case once untimed and then best
of ``--repeat`` consecutive runs; the kernel (sys) time of that best run is
printed too, since fresh memory pages are expensive on some virtual machines:

* the blurs alone: `scipy.ndimage.gaussian_filter` with sigma = 5 on each band
  and sigma = 3 on their (precomputed) sum, the three blurs the filter runs on
  images without invalid pixels;
* ``PointSourceFilter()`` (blurs + two Numba passes);
* the same chain in plain numpy (``numpy_chain`` of ``tests/test_detection.py``);
* ``find_point_sources`` (filter + photutils segmentation and catalogue).

The target is filter / blurs <= 1.25. The filter's maps are checked against
the numpy chain before timing. Also reported: where the best
``PointSourceFilter()`` run spends its time outside the blurs (the two Numba
passes, the finiteness checks, the noise and low-level estimates), and the
import plus the first call of ``find_point_sources`` on a small image in a
fresh interpreter, with an empty and with a warm Numba cache. With
``--output FILE`` the figures also go to FILE: ``docs/detection.rst`` quotes
``docs/_static/detection/timings.txt`` through
``docs/scripts/detection_numbers.py``.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _output import Record, add_output_argument  # noqa: E402
from test_detection import numpy_chain  # noqa: E402

from lensdual.detection import PointSourceFilter, _kernels, core, find_point_sources  # noqa: E402

#: The steps of the filter timed inside a call: (module, attribute, label).
STEPS = ((_kernels, "band_statistics", "first Numba pass (band statistics, co-add)"),
         (_kernels, "filter_pixels", "second Numba pass (residuals to candidates)"),
         (_kernels, "has_nonfinite", "finiteness checks"),
         (core, "_residual_noise", "noise estimate"),
         (core, "_low_level", "low-level estimate"))

#: Import plus a first call in a fresh interpreter.
_FIRST_CALL = """
import numpy as np
from lensdual.detection import find_point_sources
rng = np.random.default_rng(0)
y, x = np.mgrid[:64, :64]
star = 50 * np.exp(-0.5 * ((x - 30.3) ** 2 + (y - 31.6) ** 2))
assert len(find_point_sources({b: star + rng.normal(size=x.shape) for b in "ab"})) == 1
"""


def make_bands(size, n_sources=800, seed=0):
    """Two bands: a wide arc across the image, point sources, Gaussian noise (sigma 1)."""
    rng = np.random.default_rng(seed)
    y, x = np.ogrid[:size, :size]
    rho = np.hypot(x - size / 2, y + size / 4)
    radius = 0.9 * size
    arc = np.exp(-0.5 * ((rho - radius) / 10.0) ** 2)
    del rho
    on_arc = rng.random(n_sources) < 0.5
    phi = rng.uniform(-0.5, 0.5, n_sources)
    r = radius + rng.normal(scale=4.0, size=n_sources)
    sx = np.where(on_arc, size / 2 + r * np.sin(phi), rng.uniform(10, size - 10, n_sources))
    sy = np.where(on_arc, -size / 4 + r * np.cos(phi), rng.uniform(10, size - 10, n_sources))
    keep = (sx > 10) & (sx < size - 10) & (sy > 10) & (sy < size - 10)
    sx, sy = sx[keep], sy[keep]
    flux = rng.uniform(250, 450, sx.size)
    bands = {}
    for band, psf, peak, colour in (("F150W", 0.85, 100.0, 1.0), ("F200W", 1.0, 80.0, 0.9)):
        img = peak * arc
        img = img + rng.normal(size=(size, size))
        for xs, ys, f in zip(sx, sy, flux, strict=True):
            i0, j0 = int(round(ys)), int(round(xs))
            yy, xx = np.mgrid[i0 - 6 : i0 + 7, j0 - 6 : j0 + 7]
            img[i0 - 6 : i0 + 7, j0 - 6 : j0 + 7] += (
                colour * f / (2 * np.pi * psf**2)
                * np.exp(-0.5 * ((xx - xs) ** 2 + (yy - ys) ** 2) / psf**2)
            )  # fmt: skip
        bands[band] = img
    return bands, sx.size


class StepTimer:
    """Wrap the steps of ``STEPS`` so that each call adds its wall time to a total."""

    def __init__(self):
        self.totals = dict.fromkeys((label for _, _, label in STEPS), 0.0)
        self._saved = []

    def __enter__(self):
        for module, name, label in STEPS:
            func = getattr(module, name)
            self._saved.append((module, name, func))
            setattr(module, name, self._timed(func, label))
        return self

    def __exit__(self, *exc):
        for module, name, func in self._saved:
            setattr(module, name, func)
        self._saved = []

    def _timed(self, func, label):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return func(*args, **kwargs)
            finally:
                self.totals[label] += time.perf_counter() - start
        return timed


def first_call():
    """Wall time (s) of import plus a first call, fresh interpreter: empty, then warm cache."""
    times = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for _ in range(2):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True,
                           capture_output=True)
            times.append(time.perf_counter() - start)
    return times


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=4096)
    parser.add_argument("--repeat", type=int, default=5)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()

    bands, n_sources = make_bands(args.size)
    a, b = bands["F150W"], bands["F200W"]
    coadd = a + b
    filt = PointSourceFilter()

    # compile (or load from the Numba cache), and check against the numpy chain
    filt({k: v[:64, :64].copy() for k, v in bands.items()})
    result = filt(bands)
    ref = numpy_chain([a, b])
    np.testing.assert_array_equal(result.candidates, ref["candidates"])
    np.testing.assert_allclose(result.normalized, ref["normalized"], rtol=1e-12, atol=0)
    del ref, result

    def blurs():
        gaussian_filter(a, 5.0)
        gaussian_filter(b, 5.0)
        gaussian_filter(coadd, 3.0)

    cases = {
        "blurs (2 x sigma 5, 1 x sigma 3)": blurs,
        "PointSourceFilter": lambda: filt(bands),
        "numpy chain": lambda: numpy_chain([a, b]),
        "find_point_sources": lambda: find_point_sources(bands),
    }
    best, steps = {}, None
    for name, func in cases.items():
        func()  # warm-up: the first run of a case also pays for fresh memory pages
        runs = []
        for _ in range(args.repeat):
            with StepTimer() as timer:
                r0 = resource.getrusage(resource.RUSAGE_SELF)
                start = time.perf_counter()
                func()
                wall = time.perf_counter() - start
                r1 = resource.getrusage(resource.RUSAGE_SELF)
            runs.append((wall, r1.ru_stime - r0.ru_stime))
            if name == "PointSourceFilter" and wall == min(runs)[0]:
                steps = timer.totals
        best[name] = min(runs)

    table = find_point_sources(bands)
    ref_time = best["blurs (2 x sigma 5, 1 x sigma 3)"][0]
    rec.say(
        f"two {args.size} x {args.size} float64 bands, {n_sources} injected point sources, "
        f"{len(table)} found; best of {args.repeat}"
    )
    rec.say(f"{'':<36}{'time [s]':>10}{'/ blurs':>10}{'of it sys [s]':>15}")
    for name, (t, sys_t) in best.items():
        rec.say(f"{name:<36}{t:>10.3f}{t / ref_time:>10.2f}{sys_t:>15.3f}")
    rec.say("steps of the best PointSourceFilter run:")
    for label, t in steps.items():
        rec.say(f"  {label:<44}{t:>8.3f} s")
    cold, warm = first_call()
    rec.say(f"import and first call of find_point_sources in a fresh interpreter: {cold:.1f} s "
            f"with an empty Numba cache, {warm:.1f} s with a warm one")
    rec.write(args.output)
    return best


if __name__ == "__main__":
    main()
