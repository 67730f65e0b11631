"""What finite-size star clusters do to today's PSF photometry and to the duality test.

Run on demand (about 25 minutes of CPU with ``--pipeline-seeds 30``)::

    python benchmarks/finite_size_bias.py [--seeds 3] [--pipeline-seeds 4] [--out FILE]

Part 1, the photometry: the demo's lens without a sub-halo (12 sources,
two bands, the demo's noise), every cluster of one half-light radius r_eff
(0 = points, then 1, 5, 10, 20, 40, 80 pc), rendered by
``render_mock_images(r_eff=...)``. The pipeline's photometry
(``measure_pairs`` with the demo's PSF images, started from the true
positions, so that detection and pairing play no part) measures every
image; reported per r_eff: the median ln(F / F_true) on each arc, the
median ln(mu_flux / mu_true) of the pairs (both bands), its 16-84 %
half-width, and the closed form of an amplitude fit of a Gaussian PSF of
width p to a Gaussian image of widths (p^2 + s_i^2)^(1/2) along the image's
principal axes: the fit recovers prod_i sqrt(2) p / sqrt(2 p^2 + s_i^2) of
the flux, with s_i = sigma * (singular values of A^-1) and
p^2 = sigma_PSF^2 + pixel^2 / 12 (the pixel-integrated PSF).

Part 2, the whole pipeline: ``lensdual demo`` as the CLI runs it (the
over-concentrated sub-halo, detection, automatic pairing, PSF astrometry
errors, the adaptive estimator; no null calibration, which does not change
the flags) on the point scene and on ``--scene realistic`` (half-light radii
log-uniform in 1-50 pc, host clumps, a cluster member, intracluster light, a
diffuse patch under the L2 image of pair 0 and poppy's hexagonal-pupil PSF)
for a few seeds, with the default PSF photometry and, on the realistic scene,
also with the resolved fit (``source_model="resolved"``, which fits every
image as the PSF convolved with an elliptical Gaussian, here with poppy's
spiked PSF); reported: false flags (flagged pairs without the sub-halo,
the patch pair apart), how often the patch pair was flagged, whether the
sub-haloed pair was flagged, and the median |size error| and
|ln(mu_flux / mu_true)| of the pairs without the sub-halo and the patch.
"""

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _scenes import patch_sources
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable

from lensdual._pairs_table import arc_xy
from lensdual.demo import DEMO_BANDS, compare_with_truth, render_demo, simulate_demo
from lensdual.photometry import measure_pairs
from lensdual.pipeline import analyse
from lensdual.simulation import PSF_FWHM, lens_to_sky, render_mock_images
from lensdual.simulation._clusters import image_covariances, source_sigmas
from lensdual.simulation.mock import _LensAdapter

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

RADII_PC = (0.0, 1.0, 5.0, 10.0, 20.0, 40.0, 80.0)
PIXEL = 0.04  # arcsec, the demo's
SQRT_8LN2 = 2.0 * math.sqrt(2.0 * math.log(2.0))


def _closed_form(system, truth, r_pc, band):
    """ln of the fraction of the flux a Gaussian amplitude fit recovers, per image (L1, L2)."""
    p2 = (PSF_FWHM[band].to_value(u.arcsec) / SQRT_8LN2) ** 2 + PIXEL ** 2 / 12
    lens = _LensAdapter(system.lens_model, system.kwargs_lens)
    _, sigma = source_sigmas(r_pc * u.pc, len(truth), system)
    out = []
    for arc in (1, 2):
        cov, _ = image_covariances(lens, arc_xy(truth, arc), sigma)
        s2 = np.linalg.eigvalsh(cov)  # (N, 2): s_i^2 along the principal axes
        out.append(np.sum(0.5 * np.log(2 * p2 / (2 * p2 + s2)), axis=1))
    return out


def photometry_bias(seeds, source_model="point", radii=RADII_PC):
    """Part 1: one row per r_eff, with measure_pairs(source_model=source_model)."""
    rows = []
    records = {r: {"l1": [], "l2": [], "ratio": [], "pred1": [], "pred2": [], "pred": [],
                   "stretch1": [], "stretch2": [], "pull": []} for r in radii}
    for seed in seeds:
        system, truth = simulate_demo(subhalo="none", seed=seed)
        for r in radii:
            mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=truth, seed=seed,
                                       r_eff=r * u.pc)
            psf = {b: np.asarray(mocks[("L1", b)].psf) for b in DEMO_BANDS}
            centre = mocks[("L1", DEMO_BANDS[0])].meta
            sky_centre = SkyCoord(centre["LENSRA"] * u.deg, centre["LENSDEC"] * u.deg)
            start = QTable({"pair_id": np.arange(1, len(truth) + 1),
                            "sky1": lens_to_sky(arc_xy(truth, 1) * u.arcsec, sky_centre),
                            "sky2": lens_to_sky(arc_xy(truth, 2) * u.arcsec, sky_centre)})
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                measured = measure_pairs(mocks.arc("L1"), mocks.arc("L2"), start, psf=psf,
                                         bands=list(DEMO_BANDS), source_model=source_model)
            rec = records[r]
            for b in DEMO_BANDS:
                f1 = measured[f"flux1_{b}"].to_value(u.nJy)
                f2 = measured[f"flux2_{b}"].to_value(u.nJy)
                t1 = truth[f"flux1_{b}"].to_value(u.nJy)
                t2 = truth[f"flux2_{b}"].to_value(u.nJy)
                with np.errstate(invalid="ignore", divide="ignore"):
                    rec["l1"].append(np.log(f1 / t1))
                    rec["l2"].append(np.log(f2 / t2))
                    rec["ratio"].append(np.log((f1 / f2) / np.asarray(truth["mu_true"])))
                    e1 = measured[f"flux_err1_{b}"].to_value(u.nJy) / f1
                    e2 = measured[f"flux_err2_{b}"].to_value(u.nJy) / f2
                    rec["pull"].append(rec["ratio"][-1] / np.hypot(e1, e2))
                p1, p2 = _closed_form(system, truth, r, b)
                rec["pred1"].append(p1)
                rec["pred2"].append(p2)
                rec["pred"].append(p1 - p2)
            rec["stretch1"].append(np.asarray(mocks.pairs["stretch1"]))
            rec["stretch2"].append(np.asarray(mocks.pairs["stretch2"]))
    for r in radii:
        rec = {k: np.concatenate(v) for k, v in records[r].items()}
        ok = np.isfinite(rec["ratio"])
        q16, q84 = np.percentile(rec["ratio"][ok], [16, 84])
        p16, p84 = np.percentile(rec["pull"][ok], [16, 84])
        angle = source_sigmas(r * u.pc, 1, system)[0][0] * 1e3
        rows.append((r, angle, np.median(rec["stretch1"]), np.median(rec["stretch2"]),
                     np.nanmedian(rec["l1"]), np.median(rec["pred1"]),
                     np.nanmedian(rec["l2"]), np.median(rec["pred2"]),
                     np.median(rec["ratio"][ok]), 0.5 * (q84 - q16), np.median(rec["pred"]),
                     int(ok.sum()), 0.5 * (p84 - p16)))
    return rows


#: Part 2's rows: (scene, source model of the photometry).
PIPELINE_ROWS = (("point", "point"), ("realistic", "point"), ("realistic", "resolved"))


def pipeline_flags(seeds, rows=PIPELINE_ROWS):
    """Part 2: per scene and source model, the flags of the whole pipeline over the seeds."""
    out = {}
    for scene, source_model in rows:
        false_flags, tested, found, size_err, ratio_err = 0, 0, 0, [], []
        patch_flags = 0
        for seed in seeds:
            system, truth = simulate_demo(seed=seed)
            demo = render_demo(system, truth, seed=seed, scene=scene)
            analysis = analyse(demo.images, psf=demo.psf, sigma_pos="auto", seed=seed,
                               null_realisations=0, source_model=source_model,
                               **GEOMETRIC)
            comp = compare_with_truth(analysis.result, truth, demo.centre)
            pairs = demo.mocks.pairs
            sub = np.asarray(comp["subhalo"], dtype=bool)
            # the source whose image lies on the realistic scene's diffuse patch
            on = np.isin(np.asarray(comp["source"]), patch_sources(pairs)) & ~sub
            on_patch = int(np.sum(on & np.asarray(comp["anomalous"], bool)))
            false_flags += comp.meta["false_flags"] - on_patch
            patch_flags += on_patch
            tested += int(np.sum(np.isfinite(np.asarray(analysis.result["mu_size"],
                                                        dtype=float))))
            found += bool(comp.meta["subhalo_flagged"])
            clean = ~sub & ~on
            size_err.append(np.abs(np.asarray(comp["size_error"], dtype=float))[clean])
            ratio_err.append(np.abs(np.log(np.asarray(comp["mu_flux"], dtype=float)
                                           / np.asarray(comp["mu_true"], dtype=float)))[clean])
        out[scene, source_model] = (false_flags, patch_flags, tested, found, len(seeds),
                      np.nanmedian(np.concatenate(size_err)),
                      np.nanmedian(np.concatenate(ratio_err)))
    return out


def format_results(bias, flags, seeds, pipeline_seeds):
    lines = [
        "Finite-size star clusters and today's PSF photometry (benchmarks/finite_size_bias.py)",
        "",
        f"1. Photometry bias: demo lens without sub-halo, 12 sources x {len(seeds)} seeds "
        f"{list(seeds)} x 2 bands,",
        "   measure_pairs from the true positions; ln values are medians over images/pairs;",
        "   'pred' is the closed form of a Gaussian PSF amplitude fit (see the script).",
        "",
        " r_eff  r_eff  stretch  stretch  ln F/Ftrue  pred   ln F/Ftrue  pred   "
        "ln(mu_flux/mu_true)  pred   pairs",
        "  [pc]  [mas]       L1       L2          L1    L1           L2    L2   "
        "median  16-84%/2",
    ]
    for (r, ang, s1, s2, l1, p1, l2, p2, ratio, width, pred, n, _) in bias:
        lines.append(f"{r:6.0f} {ang:6.2f} {s1:8.2f} {s2:8.2f} {l1:+11.3f} {p1:+6.3f} "
                     f"{l2:+12.3f} {p2:+6.3f}   {ratio:+6.3f}  {width:8.3f}  {pred:+6.3f}  "
                     f"{n:5d}")
    lines += [
        "",
        f"2. The whole pipeline (lensdual demo: over-concentrated sub-halo, adaptive "
        f"estimator), seeds {list(pipeline_seeds)}:",
        "",
        " scene       photometry  false flags / pairs tested  patch pair flagged  "
        "sub-halo flagged  median |size error|  median |ln mu_flux/mu_true|",
    ]
    for (scene, model), (ff, pf, tested, found, n, size_err, ratio_err) in flags.items():
        patch = f"{pf} of {n}" if scene == "realistic" else "-"
        lines.append(f" {scene:10s}  {model:10s}  {ff:5d} / {tested:<20d}  {patch:<18s}  "
                     f"{found} of {n:<13d} {size_err:18.3f}  {ratio_err:26.3f}")
    lines += ["",
              "   false flags: flagged pairs without the sub-halo; the realistic scene's patch",
              "   pair (pair 0, a diffuse patch under its L2 image) is counted apart, and left out",
              "   of the median errors;",
              "   photometry: the source model of the PSF fit ('point', the default, or",
              "   'resolved', the PSF convolved with an elliptical Gaussian)."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds of part 1")
    parser.add_argument("--pipeline-seeds", type=int, default=4, help="seeds of part 2")
    parser.add_argument("--out", type=Path, default=None, help="also write the results here")
    args = parser.parse_args(argv)
    start = time.process_time()
    seeds = tuple(range(args.seeds))
    pipeline_seeds = tuple(range(args.pipeline_seeds))
    bias = photometry_bias(seeds)
    flags = pipeline_flags(pipeline_seeds)
    text = format_results(bias, flags, seeds, pipeline_seeds)
    print(text)
    print(f"({time.process_time() - start:.0f} s of CPU)", file=sys.stderr)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)


if __name__ == "__main__":
    main()
