"""Peak memory and time of a full-frame two-arc, two-band run.

Run on demand (not part of the test suite)::

    python benchmarks/bench_memory_run.py [--size 4096] [--cases detect,photometry,run]
                                          [--no-error] [--output FILE]

Builds, in process and without FITS files, what ``lensdual run`` hands to
:func:`lensdual.pipeline.analyse`: two arcs x two bands of ``size x size`` float64
`~astropy.nddata.CCDData` (nJy) with a TAN WCS, Gaussian sky noise (sigma 1,
sky subtracted), a faint smooth arc in a region of about 600 x 600 pixels, 20
Gaussian point sources along it and, unless ``--no-error``, an error map
(`~astropy.nddata.StdDevUncertainty`, float64, of the size of the image).

Each case runs in a fresh subprocess (so that neither the Numba compilation
of the previous case nor its freed memory counts):

* ``detect``: :func:`lensdual.detection.find_point_sources` on each arc's
  dict of bands (as ``pipeline._catalogue``);
* ``photometry``: :func:`lensdual.photometry.psf_photometry` of every band of
  each arc at the true source positions (as ``pipeline._catalogue``), then
  :func:`lensdual.photometry.measure_pairs` of the 20 true pairs (as
  ``pipeline.analyse``);
* ``run``: both, in that order (the pipeline's image work).

Printed per case: the peak resident set size of the whole process
(``VmHWM`` after resetting it once the inputs are built, i.e. inputs
included; ``ru_maxrss`` where that reset is unavailable), the size of the
inputs (data arrays only, and data + error maps), the ratio of the peak to
the data arrays (the measure its target is set in), the extra memory above the resident
size once the inputs were built, and the wall time of the case (the Numba
kernels are compiled or loaded from their cache before the clock starts).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np
from _output import Record, add_output_argument

N_SOURCES = 20
FWHM = {"F150W": 2.0, "F200W": 2.4}
SCALE = 0.03  # arcsec / pixel


def make_wcs(size, crval):
    from astropy.wcs import WCS

    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = list(crval)
    w.wcs.crpix = [size / 2 + 0.5, size / 2 + 0.5]
    w.wcs.cdelt = [-SCALE / 3600, SCALE / 3600]
    return w


def source_positions(size, arc):
    """(x, y) of the sources on an arc-like stripe (a circle segment) of ~600 px."""
    rng = np.random.default_rng(100 + arc)
    cx, cy = (0.35 if arc == 1 else 0.62) * size, (0.40 if arc == 1 else 0.58) * size
    radius = 400.0
    phi = np.linspace(-0.6, 0.6, N_SOURCES) + rng.uniform(-0.01, 0.01, N_SOURCES)
    x = cx + radius * np.sin(phi)
    y = cy - radius + radius * np.cos(phi)
    return x, y, (cx, cy - radius, radius)


def make_arc(size, arc, with_error, seed=0):
    """dict band -> CCDData of one arc; built in place (peak ~ the images themselves)."""
    from astropy import units as u
    from astropy.nddata import CCDData, StdDevUncertainty

    x, y, (ox, oy, radius) = source_positions(size, arc)
    wcs = make_wcs(size, (150.0, 2.0))
    rng = np.random.default_rng(seed + 10 * arc)
    # the arc's smooth light and the point sources only in a box about the stripe
    x0, x1 = int(x.min()) - 60, int(x.max()) + 60
    y0, y1 = int(y.min()) - 60, int(y.max()) + 60
    yy, xx = np.mgrid[y0:y1, x0:x1]
    rho = np.hypot(xx - ox, yy - oy)
    ridge = 8.0 * np.exp(-0.5 * ((rho - radius) / 6.0) ** 2)
    flux = np.linspace(300.0, 900.0, N_SOURCES)
    images = {}
    for band, colour in (("F150W", 1.0), ("F200W", 0.8)):
        data = np.empty((size, size))
        rng.standard_normal(out=data)
        sig = FWHM[band] / 2.3548
        stamp = colour * ridge
        for xs, ys, f in zip(x, y, flux, strict=True):
            stamp += (
                colour
                * f
                / (2 * np.pi * sig**2)
                * np.exp(-0.5 * ((xx - xs) ** 2 + (yy - ys) ** 2) / sig**2)
            )
        data[y0:y1, x0:x1] += stamp
        unc = None
        if with_error:
            err = np.empty((size, size))
            err.fill(1.0)
            unc = StdDevUncertainty(err, copy=False)
        images[band] = CCDData(data, unit=u.nJy, wcs=wcs, uncertainty=unc, copy=False)
    return images


def _rss_now():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def warm_up():
    """Compile (or load from the cache) the kernels on a small image."""
    import warnings

    from lensdual.detection import find_point_sources
    from lensdual.photometry import psf_photometry

    images = make_arc(1024, 1, True)
    x, y, _ = source_positions(1024, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        find_point_sources(images)
        psf_photometry(images["F150W"], np.column_stack([x, y])[:3], warn=False)


def child(case, size, with_error):
    import warnings

    from astropy.table import QTable

    from lensdual.detection import find_point_sources
    from lensdual.photometry import measure_pairs, psf_photometry

    warm_up()
    arcs = {name: make_arc(size, k, with_error) for k, name in ((1, "L1"), (2, "L2"))}
    data_bytes = sum(im.data.nbytes for a in arcs.values() for im in a.values())
    err_bytes = sum(
        im.uncertainty.array.nbytes
        for a in arcs.values()
        for im in a.values()
        if im.uncertainty is not None
    )
    import gc

    gc.collect()
    base = _rss_now()
    reset = _reset_peak()
    t0 = time.perf_counter()
    n_found = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if case in ("detect", "run"):
            for name, images in arcs.items():
                found = find_point_sources(images)
                n_found[name] = 0 if found is None else len(found)
                del found
        if case in ("photometry", "run"):
            skies = {}
            for k, (name, images) in enumerate(arcs.items(), start=1):
                x, y, _ = source_positions(size, k)
                for band, image in images.items():
                    phot = psf_photometry(image, np.column_stack([x, y]), warn=False)
                    if band == "F150W":
                        skies[name] = image.wcs.pixel_to_world(x, y)
                    del phot
            pairs = QTable(
                {
                    "id1": np.arange(1, N_SOURCES + 1),
                    "id2": np.arange(1, N_SOURCES + 1),
                    "sky1": skies["L1"],
                    "sky2": skies["L2"],
                }
            )
            measured = measure_pairs(arcs["L1"], arcs["L2"], pairs)
            n_found["measured"] = int(np.count_nonzero(measured["measured"]))
    elapsed = time.perf_counter() - t0
    peak = _peak()
    return {
        "case": case,
        "size": size,
        "error_maps": with_error,
        "data_MiB": data_bytes / 2**20,
        "inputs_MiB": (data_bytes + err_bytes) / 2**20,
        "base_MiB": base / 2**20,
        "peak_MiB": peak / 2**20,
        "peak_reset": reset,
        "peak_over_data": peak / data_bytes,
        "peak_over_inputs": peak / (data_bytes + err_bytes),
        "extra_MiB": (peak - base) / 2**20,
        "time_s": elapsed,
        "found": n_found,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=4096)
    parser.add_argument("--cases", default="detect,photometry,run")
    parser.add_argument("--no-error", action="store_true", help="no error maps")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    add_output_argument(parser)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.size, not args.no_error)))
        return
    rec = Record()
    rec.say(f"# size {args.size}, error maps: {not args.no_error}")
    rec.say(
        f"{'case':<11}{'data MiB':>9}{'inputs MiB':>11}{'peak MiB':>9}{'peak/data':>10}"
        f"{'peak/inputs':>12}{'extra MiB':>10}{'time s':>8}  found"
    )
    for case in args.cases.split(","):
        cmd = [sys.executable, __file__, "--child", case, "--size", str(args.size)]
        if args.no_error:
            cmd.append("--no-error")
        out = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if out.returncode:
            rec.say(f"{case}: failed\n{out.stderr[-3000:]}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rec.say(
            f"{case:<11}{r['data_MiB']:9.0f}{r['inputs_MiB']:11.0f}{r['peak_MiB']:9.0f}"
            f"{r['peak_over_data']:10.2f}{r['peak_over_inputs']:12.2f}{r['extra_MiB']:10.0f}"
            f"{r['time_s']:8.1f}  {r['found']}"
            + ("" if r["peak_reset"] else "  (ru_maxrss: peak since start)")
        )
    rec.write(args.output)


if __name__ == "__main__":
    main()
