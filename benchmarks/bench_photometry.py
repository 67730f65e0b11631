"""Speed of the PSF photometry on the arc scenes of tests/test_photometry.py.

Run on demand (about a minute)::

    python benchmarks/bench_photometry.py [--repeat 3] [--output FILE]

Two timings, best of ``--repeat``, in one process after a warm-up call (so
the Numba kernels are compiled or loaded from the cache before any timing),
each as wall time and as the process's CPU time (which a busy machine
changes less):

* per isolated source, for the ``"ridge"`` (default), ``"plane"`` and
  ``"residual"`` background strategies, on the tests' scene (a bright curved
  arc of 110 x 200 pixels, sources every ~14 px along it and a few off it),
  with the ratio of each to ``"ridge"``;
* a larger image (400 x 600 pixels, two concentric arcs of the same profile,
  sources along both and a few off them) with the default strategy, with
  the PSF's FWHM given and with ``psf=None`` (the FWHM is then fitted
  first), and the ratio of the two.

Also printed: the fraction of a Gaussian point source's least-squares flux
that the high-pass filter of the ``"residual"`` strategy removes (the
pixel-integrated PSF of 2.5 px FWHM minus its blur by a Gaussian of 5 px),
which is why that strategy filters its PSF model too. With ``--output FILE``
the figures also go to FILE: ``docs/photometry.rst`` quotes
``docs/_static/photometry/speed.txt`` through
``docs/scripts/photometry_numbers.py``.
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _output import Record, add_output_argument  # noqa: E402
from test_photometry import FWHM, arc_image, arc_sources, prf, render  # noqa: E402

from lensdual.photometry import psf_photometry  # noqa: E402

#: The strategies timed per isolated source; the first is the reference.
STRATEGIES = ("ridge", "plane", "residual")
#: The larger image: its shape, and the radii of its two arcs, centred below it.
LARGE_SHAPE = (400, 600)
LARGE_RADII = (420.0, 560.0)
#: The blur of the high-pass filter of the "residual" strategy (px).
SMOOTH_SIGMA = 5.0


def best_of(func, repeat):
    """The shortest wall and CPU times (s) of ``repeat`` calls of ``func``."""
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        func()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return min(wall), min(cpu)


def scene(seed=11):
    """The tests' arc image with point sources, and starting positions 0.3 px off."""
    rng = np.random.default_rng(seed)
    xy, flux = arc_sources(rng)
    image, _ = render(arc_image(), xy, flux, rng)
    return image, xy + rng.normal(scale=0.3, size=xy.shape)


def large_scene(seed=12):
    """Two concentric arcs on a ``LARGE_SHAPE`` image, with their point sources."""
    rng = np.random.default_rng(seed)
    ny, nx = LARGE_SHAPE
    background = np.zeros(LARGE_SHAPE)
    xy, flux = [], []
    for k, radius in enumerate(LARGE_RADII):
        # the crests cross the middle column at a third and two thirds of the height
        centre = (nx / 2, (k + 1) * ny / 3 - radius)
        background += arc_image(LARGE_SHAPE, centre, radius)
        more_xy, more_flux = arc_sources(rng, centre=centre, radius=radius, shape=LARGE_SHAPE)
        xy.append(more_xy)
        flux.append(more_flux)
    xy, flux = np.concatenate(xy), np.concatenate(flux)
    image, _ = render(background, xy, flux, rng)
    return image, xy + rng.normal(scale=0.3, size=xy.shape)


def filtered_flux_loss(fwhm=FWHM, sigma=SMOOTH_SIGMA, size=101):
    """The fraction of a pixel-integrated Gaussian PSF's least-squares flux that
    subtracting its blur by a Gaussian of ``sigma`` px removes."""
    yy, xx = np.mgrid[:size, :size] - size // 2
    psf = prf(xx, yy, fwhm)
    filtered = psf - gaussian_filter(psf, sigma, mode="constant")
    return 1.0 - np.sum(psf * filtered) / np.sum(psf * psf)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="best of (default 3)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    warnings.simplefilter("ignore")

    image, start = scene()
    for strategy in STRATEGIES:
        psf_photometry(image, start, psf=FWHM, background=strategy)
    rec.say(f"isolated sources: {len(start)} on a {image.shape[0]} x {image.shape[1]} arc "
            f"image, FWHM {FWHM} px; best of {args.repeat}")
    rec.say(f"{'background':<12}{'wall ms/source':>16}{'CPU ms/source':>15}{'CPU / ridge':>13}")
    per = {}
    for strategy in STRATEGIES:
        wall, cpu = best_of(
            lambda s=strategy: psf_photometry(image, start, psf=FWHM, background=s), args.repeat)
        per[strategy] = 1e3 * cpu / len(start)
        rec.say(f"{strategy:<12}{1e3 * wall / len(start):>16.2f}{per[strategy]:>15.2f}"
                f"{per[strategy] / per[STRATEGIES[0]]:>13.2f}")

    image, start = large_scene()
    psf_photometry(image, start, psf=None)
    rec.say(f"large image: {len(start)} sources on {image.shape[0]} x {image.shape[1]} px, "
            "two arcs")
    times = {}
    for label, psf in (("psf=FWHM", FWHM), ("psf=None", None)):
        times[label] = best_of(lambda p=psf: psf_photometry(image, start, psf=p), args.repeat)
        wall, cpu = times[label]
        rec.say(f"  {label}: wall {wall:.2f} s, CPU {cpu:.2f} s")
    ratio = times["psf=None"][1] / times["psf=FWHM"][1]
    rec.say(f"  psf=None / psf=FWHM, CPU: {ratio:.2f}")
    rec.say(f"high-pass filter (sigma {SMOOTH_SIGMA:g} px) removes "
            f"{100 * filtered_flux_loss():.1f} % of the least-squares flux of a "
            f"{FWHM} px FWHM point source")
    rec.write(args.output)


if __name__ == "__main__":
    main()
