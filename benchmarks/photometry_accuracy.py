"""Accuracy of the PSF photometry's background strategies on the arc scenes of
tests/test_photometry.py.

Run on demand (a few minutes on one core)::

    python benchmarks/photometry_accuracy.py [--realisations 8] [--snr-realisations 20]
        [--variant-realisations 4] [--output FILE]

The scene is the tests' one: a 110 x 200 px image, a Gaussian PSF of FWHM
2.5 px, a curved arc (radius of curvature 190 px) with a cored exponential
cross profile, blurred by the PSF, 13 point sources along it at -5 to +5 px
across it plus 4 off it, read noise 1 plus photon noise (gain 20), starting
positions 0.3 px off. Printed:

* the strategy comparison on the arc of crest ``A`` = 40 and ``A`` = 100 per
  pixel (``--realisations`` noise realisations, the sources on the arc only);
* the same without the arc (``A`` = 0, every source);
* a harder arc: an elongated, curved exponential (Sersic n = 1) galaxy with its
  centre inside the image and a compact knot (Gaussian, sigma 3 px) at 0.3 of
  its peak, crest 100 per pixel;
* the accuracy of the default fit against the SNR (``A`` = 40, fluxes 40 - 6000,
  ``--snr-realisations`` realisations);
* the flux pull standard deviation of ``"ridge"`` and ``"quadratic"`` on
  variants of the scene (crest 50 per pixel; radius of curvature 80 and 50 px;
  FWHM 1.6 and 4 px; ``--variant-realisations`` realisations each).

The SNR of a source is its flux over the smallest possible flux error (known
position and background); the pull is (fitted - true flux) / reported error.
With ``--output FILE`` the lines also go to FILE: ``docs/photometry.rst``
quotes ``docs/_static/photometry/accuracy.txt`` through
``docs/scripts/photometry_numbers.py``.
"""

import argparse
import copy
import sys
import warnings
from pathlib import Path

import numpy as np
from astropy import units as u
from scipy.ndimage import gaussian_filter

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _output import Record, add_output_argument  # noqa: E402
from test_photometry import (  # noqa: E402
    ARC_CENTRE,
    ARC_RADIUS,
    FWHM,
    GAIN,
    READ_NOISE,
    SHAPE,
    arc_image,
    arc_sources,
    crb_flux_error,
    prf,
    render,
)

from lensdual.photometry import BACKGROUND_STRATEGIES, psf_photometry  # noqa: E402

#: The strategies in the order of the comparison tables.
ORDER = ("none", "local", "constant", "plane", "quadratic", "residual", "residual-plane",
         "ridge")
#: The SNR bins of the accuracy table (lower edges; the last is open).
SNR_EDGES = (5.0, 10.0, 20.0, 30.0, 60.0, 120.0, np.inf)
#: The SNR from which the median ln and the positions are quoted.
HIGH_SNR = 30.0
#: The harder arc: crest, exponential scales along and across it (px), the knot's
#: offset along the arc (px), its sigma (px) and its peak relative to the crest.
HARD_PEAK = 100.0
HARD_SCALES = (40.0, 3.0)
HARD_KNOT = (25.0, 3.0, 0.3)
#: The variants: (label, radius of curvature, FWHM), crest VARIANT_PEAK.
VARIANT_PEAK = 50.0
VARIANTS = (("radius 80 px", 80.0, FWHM), ("radius 50 px", 50.0, FWHM),
            ("FWHM 1.6 px", ARC_RADIUS, 1.6), ("FWHM 4 px", ARC_RADIUS, 4.0))
#: Seeds of the first realisation of each study.
SEEDS = {"comparison": 1000, "hard": 2000, "snr": 3000, "variants": 4000}


def on_arc_sources(rng, **kwargs):
    """``arc_sources(rng, **kwargs)`` and the mask of the sources on the arc (those
    not among the ones placed off it)."""
    xy, flux = arc_sources(copy.deepcopy(rng), **kwargs)
    arc_xy, _ = arc_sources(copy.deepcopy(rng), **(kwargs | {"n_off": 0}))
    arc_sources(rng, **kwargs)  # advance ``rng`` as the first call did
    on = np.array([np.any(np.all(p == arc_xy, axis=1)) for p in xy])
    return xy, flux, on


def hard_arc_image(shape=SHAPE, centre=ARC_CENTRE, radius=ARC_RADIUS, fwhm=FWHM, oversample=3):
    """The harder arc: a curved exponential galaxy centred where the crest crosses
    the middle column, with a Gaussian knot on the crest, PSF-blurred."""
    ny, nx = shape
    yy, xx = np.mgrid[: ny * oversample, : nx * oversample]
    xx = (xx + 0.5) / oversample - 0.5
    yy = (yy + 0.5) / oversample - 0.5
    rho = np.hypot(xx - centre[0], yy - centre[1])
    s = rho * np.arctan2(xx - centre[0], yy - centre[1])
    d = rho - radius
    along, across = HARD_SCALES
    offset, sigma, height = HARD_KNOT
    img = HARD_PEAK * (np.exp(-np.hypot(s / along, d / across))
                       + height * np.exp(-((s - offset) ** 2 + d**2) / (2 * sigma**2)))
    img = gaussian_filter(img, fwhm / 2.3548 * oversample)
    return img.reshape(ny, oversample, nx, oversample).mean(axis=(1, 3))


def variant_sources(rng, centre, radius, shape=SHAPE, spacing=14.0,
                    offsets=(-5.0, -2.5, 0.0, 2.5, 5.0), flux_range=(150.0, 4000.0)):
    """Sources along an arc of any radius (as ``arc_sources`` without the ones off
    it), over the part of the arc at least 9 px inside the image."""
    ny, nx = shape
    reach = [np.pi / 2]
    if (nx / 2 - 9) < radius:
        reach.append(np.arcsin((nx / 2 - 9) / radius))
    if 0 < 9 - centre[1] < radius:
        reach.append(np.arccos((9 - centre[1]) / radius))
    phi_max = min(reach)
    n = int(2 * phi_max * radius / spacing)
    xy = []
    for k, phi in enumerate(np.linspace(-phi_max, phi_max, n)):
        rho = radius + offsets[k % len(offsets)] + rng.uniform(-0.5, 0.5)
        xy.append((centre[0] + rho * np.sin(phi), centre[1] + rho * np.cos(phi)))
    xy = np.array(xy)
    keep = (xy[:, 0] > 8) & (xy[:, 0] < nx - 9) & (xy[:, 1] > 8) & (xy[:, 1] < ny - 9)
    xy = xy[keep]
    return xy, np.exp(rng.uniform(*np.log(flux_range), len(xy)))


def realisation(background, xy, flux, rng, strategies, fwhm=FWHM):
    """Fit one noise realisation with each strategy: {strategy: per-source arrays}."""
    image, var = render(background, xy, flux, rng, fwhm=fwhm)
    start = xy + rng.normal(scale=0.3, size=xy.shape)
    crb = crb_flux_error(xy, var, fwhm)
    out = {}
    for strategy in strategies:
        res = psf_photometry(image, start, psf=fwhm, background=strategy)
        out[strategy] = {
            "true": flux, "crb": crb,
            "flux": res["flux"].to_value(u.nJy), "err": res["flux_err"].to_value(u.nJy),
            "dx": np.asarray(res["x_fit"]) - xy[:, 0], "dy": np.asarray(res["y_fit"]) - xy[:, 1],
            "ex": np.asarray(res["x_err"]), "ey": np.asarray(res["y_err"]),
        }
    return out


def pooled(runs, strategy, masks):
    """The per-source arrays of ``strategy`` over the realisations, each cut to its mask."""
    return {key: np.concatenate([r[strategy][key][m] for r, m in zip(runs, masks, strict=True)])
            for key in runs[0][strategy]}


def statistics(p, select=None):
    """The quoted statistics of the pooled arrays ``p`` (optionally of a subset)."""
    if select is not None:
        p = {k: v[select] for k, v in p.items()}
    snr = p["true"] / p["crb"]
    with np.errstate(invalid="ignore", divide="ignore"):
        ln = np.log(p["flux"] / p["true"])
        pull = (p["flux"] - p["true"]) / p["err"]
        pos_pull = np.concatenate([p["dx"] / p["ex"], p["dy"] / p["ey"]])
    good = np.isfinite(pull)
    high = (snr >= HIGH_SNR) & good
    dr2 = p["dx"] ** 2 + p["dy"] ** 2
    return {
        "n": snr.size, "bad": int(np.sum(~good)),
        "med_ln": np.median(ln[high]), "med_abs_ln": np.median(np.abs(ln[high])),
        "rms_ln": np.sqrt(np.mean(ln[good & np.isfinite(ln)] ** 2)),
        "pull_mean": np.mean(pull[good]), "pull_std": np.std(pull[good]),
        "err_crb": np.median(p["err"][good] / p["crb"][good]),
        "pos_rms": np.sqrt(np.mean(dr2[high])), "pos_rms_all": np.sqrt(np.mean(dr2[good])),
        "pos_pull_std": np.std(pos_pull[np.isfinite(pos_pull)]),
    }


COLUMNS = ("med_ln", "med_abs_ln", "pull_mean", "pull_std", "err_crb", "pos_rms",
           "pos_pull_std")
#: The columns printed with their sign.
SIGNED = ("med_ln", "pull_mean")


def say_table(rec, stats):
    """Print the comparison table of ``{strategy: statistics}``."""
    rec.say(f"  {'background':<16}" + "".join(f"{c:>14}" for c in COLUMNS) + f"{'n':>6}"
            f"{'unfit':>7}")
    for strategy in ORDER:
        s = stats[strategy]
        cells = "".join(f"{s[c]:>{'+' if c in SIGNED else ''}14.4f}" for c in COLUMNS)
        rec.say(f"  {strategy:<16}{cells}{s['n']:>6}{s['bad']:>7}")


def comparison(rec, peak, n_real, *, all_sources=False):
    """The comparison table on the tests' arc of crest ``peak`` per pixel."""
    background = arc_image(peak=peak) if peak else np.zeros(SHAPE)
    runs, masks = [], []
    for k in range(n_real):
        rng = np.random.default_rng(SEEDS["comparison"] + k)
        xy, flux, on = on_arc_sources(rng)
        runs.append(realisation(background, xy, flux, rng, ORDER))
        masks.append(np.ones_like(on) if all_sources else on)
    stats = {s: statistics(pooled(runs, s, masks)) for s in ORDER}
    peak_px = prf(0.0, 0.0)
    which = "all sources" if all_sources else "sources on the arc"
    rec.say(f"comparison, A = {peak:g}: {stats['ridge']['n']} {which}, {n_real} realisations")
    if peak:
        rec.say(f"  crest noise {np.sqrt(READ_NOISE**2 + peak / GAIN):.2f}; source peaks "
                f"{150 * peak_px / peak:.2f} - {4000 * peak_px / peak:.1f} times the crest")
    say_table(rec, stats)
    return stats


def hard_arc(rec, n_real):
    """The comparison table on the harder arc."""
    background = hard_arc_image()
    runs, masks = [], []
    for k in range(n_real):
        rng = np.random.default_rng(SEEDS["hard"] + k)
        xy, flux, on = on_arc_sources(rng)
        runs.append(realisation(background, xy, flux, rng, ORDER))
        masks.append(on)
    stats = {s: statistics(pooled(runs, s, masks)) for s in ORDER}
    rec.say(f"harder arc (exponential galaxy, scales {HARD_SCALES[0]:g} x {HARD_SCALES[1]:g} px, "
            f"knot sigma {HARD_KNOT[1]:g} px at {HARD_KNOT[2]:g} of the peak), crest "
            f"{HARD_PEAK:g}: {stats['ridge']['n']} sources on the arc, {n_real} realisations")
    say_table(rec, stats)
    return stats


def snr_table(rec, n_real, peak=40.0):
    """The default fit's accuracy in bins of SNR."""
    background = arc_image(peak=peak)
    runs, masks = [], []
    for k in range(n_real):
        rng = np.random.default_rng(SEEDS["snr"] + k)
        xy, flux, on = on_arc_sources(rng, flux_range=(40.0, 6000.0))
        runs.append(realisation(background, xy, flux, rng, ("ridge",)))
        masks.append(on)
    p = pooled(runs, "ridge", masks)
    snr = p["true"] / p["crb"]
    rec.say(f"accuracy against SNR, default settings, A = {peak:g}: {snr.size} sources on the "
            f"arc from {n_real} realisations, fluxes 40 - 6000")
    rec.say(f"  {'SNR':<12}{'n':>5}{'med_ln':>10}{'rms_ln':>10}{'pull_mean':>11}{'pull_std':>10}"
            f"{'pos_rms':>10}{'pos_pull_std':>14}")
    edges = (0.0,) + SNR_EDGES if np.any(snr < SNR_EDGES[0]) else SNR_EDGES
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (snr >= lo) & (snr < hi)
        label = f"> {lo:g}" if np.isinf(hi) else f"{lo:g} - {hi:g}"
        if not sel.any():
            rec.say(f"  {label:<12}{0:>5}")
            continue
        s = statistics(p, sel)
        with np.errstate(invalid="ignore", divide="ignore"):
            ln = np.log(p["flux"][sel] / p["true"][sel])
        rec.say(f"  {label:<12}{s['n']:>5}{np.median(ln):>+10.4f}{s['rms_ln']:>10.4f}"
                f"{s['pull_mean']:>+11.3f}{s['pull_std']:>10.3f}{s['pos_rms_all']:>10.4f}"
                f"{s['pos_pull_std']:>14.3f}")


def variants(rec, n_real):
    """Pull standard deviations of "ridge" and "quadratic" on variants of the scene."""
    rec.say(f"scene variants, crest {VARIANT_PEAK:g} per pixel, {n_real} realisations each, "
            "sources on the arc: flux pull std")
    rec.say(f"  {'variant':<16}{'n':>5}{'ridge':>10}{'quadratic':>11}")
    for label, radius, fwhm in VARIANTS:
        centre = (SHAPE[1] / 2, 58.0 - radius)
        background = arc_image(centre=centre, radius=radius, peak=VARIANT_PEAK, fwhm=fwhm)
        runs = []
        for k in range(n_real):
            rng = np.random.default_rng(SEEDS["variants"] + k)
            xy, flux = variant_sources(rng, centre, radius)
            runs.append(realisation(background, xy, flux, rng, ("ridge", "quadratic"), fwhm))
        masks = [np.ones(r["ridge"]["true"].size, bool) for r in runs]
        s = {st: statistics(pooled(runs, st, masks)) for st in ("ridge", "quadratic")}
        rec.say(f"  {label:<16}{s['ridge']['n']:>5}{s['ridge']['pull_std']:>10.3f}"
                f"{s['quadratic']['pull_std']:>11.3f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realisations", type=int, default=8,
                        help="noise realisations per comparison table (default 8)")
    parser.add_argument("--snr-realisations", type=int, default=20,
                        help="noise realisations of the SNR table (default 20)")
    parser.add_argument("--variant-realisations", type=int, default=4,
                        help="noise realisations per scene variant (default 4)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    assert set(ORDER) == set(BACKGROUND_STRATEGIES)
    rec = Record()
    warnings.simplefilter("ignore")
    rec.say(f"photometry accuracy: realisations {args.realisations} per comparison table, "
            f"{args.snr_realisations} for the SNR table, {args.variant_realisations} per "
            "variant")
    comparison(rec, 40.0, args.realisations)
    comparison(rec, 100.0, args.realisations)
    comparison(rec, 0.0, args.realisations, all_sources=True)
    hard_arc(rec, args.realisations)
    snr_table(rec, args.snr_realisations)
    variants(rec, args.variant_realisations)
    rec.write(args.output)


if __name__ == "__main__":
    main()
