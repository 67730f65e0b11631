"""Pixels-to-pairs acceptance on mocks of the SMACS0723 analogue.

For each seed: the SMACS0723 analogue (main halo), a resolvable
constellation of 12 point sources (a jittered 3 x 4 source-plane grid around
the Table-1 source centre: the Table-1 Gaussian of sigma 0.06 arcsec puts
most images within a pixel of a neighbour at 0.04 arcsec/pixel), two-band
mock images of both arcs, then detection (App. C filter), PSF photometry at
the detected positions and, when available, automatic pairing. Prints
completeness and spurious fraction, astrometric rms vs SNR and the flux-ratio
error::

    python benchmarks/acceptance_pixels.py [--seeds 20] [--output FILE]

The docs' table (docs/mock_images.rst) is read from the stored output of
``--seeds 20 --output docs/_static/scenes/acceptance.txt`` by
``docs/scripts/mock_images_numbers.py``.
"""

import argparse
import sys
import warnings
from pathlib import Path

import astropy.units as u
import numpy as np
from astropy.table import QTable

from lensdual.detection import find_point_sources
from lensdual.pairing import pair_constellations
from lensdual.photometry import psf_photometry
from lensdual.simulation import render_mock_images, smacs0723_analog

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _output import Record, add_output_argument  # noqa: E402

BANDS = ("F150W", "F200W")


def grid_constellation(system, rng):
    gx, gy = np.meshgrid([0.35, 0.65, 0.95], [6.70, 6.82, 6.94, 7.06])
    beta = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.02, 0.02, (12, 2))
    f0 = 10 ** rng.uniform(np.log10(3.0), 1.0, 12)
    return system.constellation(beta * u.arcsec, intrinsic_flux={"F150W": f0, "F200W": 0.9 * f0},
                                seed=rng)


def run_seed(seed):
    rng = np.random.default_rng(seed)
    system = smacs0723_analog(seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = grid_constellation(system, rng)
        mocks = render_mock_images(system, pairs=truth, seed=seed)
    out = {"found": [], "snr": [], "spurious": 0, "detections": 0, "pos_err": [],
           "pos_snr": [], "ratio_err": [], "ratio_snr": [], "pairs_true": 0,
           "pairs_correct": 0, "pairs_wrong": 0, "wrong_per_system": []}
    fluxes = {}
    catalogs = {}
    truth_of = {}
    for k, arc in enumerate(("L1", "L2"), start=1):
        images = mocks.arc(arc)
        true_xy = np.asarray(mocks.truth_pixels(arc))
        snr = np.minimum(*(np.asarray(mocks.pairs[f"snr{k}_{b}"]) for b in BANDS))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cat = find_point_sources(images)
        det = (np.zeros((0, 2)) if cat is None
               else np.column_stack([cat["x_centroid"], cat["y_centroid"]]))
        d = np.hypot(*(det[:, None, :] - true_xy[None, :, :]).transpose(2, 0, 1))
        match = np.full(len(true_xy), -1)
        used = set()
        for i in np.argsort(d.min(axis=0) if len(det) else np.zeros(len(true_xy))):
            if len(det) == 0:
                break
            j = int(np.argmin(d[:, i]))
            if d[j, i] <= 2.0 and j not in used:
                match[i] = j
                used.add(j)
        out["found"].extend(match >= 0)
        out["snr"].extend(snr)
        out["detections"] += len(det)
        out["spurious"] += len(det) - len(used)
        ok = match >= 0
        if cat is not None:
            catalogs[arc] = QTable({"id": cat["id"], "sky": cat["sky_centroid"]})
            truth_of[arc] = {int(cat["id"][j]): i for i, j in enumerate(match) if j >= 0}
        for b in BANDS:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                phot = psf_photometry(images[b], det[match[ok]], warn=False)
            fluxes[(arc, b)] = np.full(len(true_xy), np.nan)
            fluxes[(arc, b)][ok] = phot["flux"]
            if cat is not None:
                flux_all = np.full(len(det), np.nan)
                flux_all[match[ok]] = phot["flux"]
                catalogs[arc][f"flux_{b}"] = flux_all
            if b == "F150W":
                fit = np.column_stack([phot["x_fit"], phot["y_fit"]])
                err = np.hypot(*(fit - true_xy[ok]).T) * 0.04  # arcsec
                out["pos_err"].extend(err)
                out["pos_snr"].extend(snr[ok])
    if len(catalogs) == 2:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pairs = pair_constellations(catalogs["L1"], catalogs["L2"], position_columns="sky",
                                        flux_columns=[f"flux_{b}" for b in BANDS], seed=seed)
        wrong = 0
        for row in pairs:
            t1 = truth_of["L1"].get(int(row["id1"]))
            t2 = truth_of["L2"].get(int(row["id2"]))
            if t1 is not None and t1 == t2:
                out["pairs_correct"] += 1
            else:
                wrong += 1
        out["pairs_wrong"] += wrong
        out["wrong_per_system"].append(wrong)
        out["pairs_true"] += len(set(truth_of["L1"].values()) & set(truth_of["L2"].values()))
    mu_true = np.asarray(mocks.pairs["mu_true"])
    snr_pair = np.minimum.reduce([np.asarray(mocks.pairs[f"snr{k}_{b}"]) for k in (1, 2)
                                  for b in BANDS])
    for b in BANDS:
        ratio = fluxes[("L1", b)] / fluxes[("L2", b)]
        good = np.isfinite(ratio)
        out["ratio_err"].extend(np.abs(np.log(ratio[good] / mu_true[good])))
        out["ratio_snr"].extend(snr_pair[good])
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    agg = {}
    for seed in range(args.seeds):
        res = run_seed(seed)
        for key, val in res.items():
            agg.setdefault(key, [] if isinstance(val, list) else 0)
            agg[key] = agg[key] + val
    found, snr = np.array(agg["found"]), np.array(agg["snr"])
    sel = snr >= 10
    rec.say(f"{args.seeds} systems, {len(found)} images")
    lo, med, hi = np.percentile(snr, [5, 50, 95])
    rec.say(f"image SNR (the lower of the two bands): median {med:.0f}, 5-95 % {lo:.0f}-{hi:.0f}")
    rec.say(f"detection completeness (SNR >= 10 in both bands): {found[sel].sum()} of "
            f"{sel.sum()} ({found[sel].mean():.1%}); all: {found.mean():.1%}")
    rec.say(f"spurious detections: {agg['spurious']} of {agg['detections']} "
            f"({agg['spurious'] / max(agg['detections'], 1):.1%})")
    err, psnr = np.array(agg["pos_err"]), np.array(agg["pos_snr"])
    for lo, hi in ((10, 20), (20, 40), (40, 80), (80, np.inf)):
        s = (psnr >= lo) & (psnr < hi)
        if s.any():
            rec.say(f"  astrometric rms, SNR {lo}-{hi}: {np.sqrt(np.mean(err[s] ** 2)):.4f} arcsec "
                    f"({s.sum()} images)")
    rec.say(f"automatic pairing: {agg['pairs_correct']} of {agg['pairs_true']} true pairs "
            f"({agg['pairs_correct'] / max(agg['pairs_true'], 1):.1%}), {agg['pairs_wrong']} wrong "
            f"(at most {max(agg['wrong_per_system'], default=0)} in one system)")
    rerr, rsnr = np.array(agg["ratio_err"]), np.array(agg["ratio_snr"])
    s = rsnr >= 30
    rec.say(f"flux ratio, both images SNR >= 30: median |ln(measured/true)| = "
            f"{np.median(rerr[s]):.2%} ({s.sum()} ratios)")
    rec.write(args.output)


if __name__ == "__main__":
    main()
