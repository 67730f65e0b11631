"""The demo over many seeds: false flags without a sub-halo, power with one.

Run on demand (about 15 s per seed and scenario on 2 cores)::

    python benchmarks/demo_calibration.py [--seeds 30]

For every seed, the demo's scenario (SMACS0723 analogue with its members, 12
sources, two-band mock images) is simulated without a sub-halo and with the
paper's over-concentrated one, the real-data pipeline runs on the images
(detection, photometry, automatic pairing, PSF astrometry errors as
sigma_pos), and the duality test runs with the adaptive estimator (the
default) and with quad2. Reported: pairs tested, clean pairs flagged (false
flags), and whether the sub-haloed pair was flagged.
"""

import argparse
import warnings

import numpy as np
from _output import Record, add_output_argument
from astropy import units as u
from astropy.coordinates import SkyCoord

from lensdual.demo import DEMO_BANDS, compare_with_truth, simulate_demo
from lensdual.duality import check_duality
from lensdual.pipeline import analyse
from lensdual.simulation import render_mock_images


def one(seed, subhalo):
    system, truth = simulate_demo(subhalo=subhalo, seed=seed)
    mocks = render_mock_images(system, bands=DEMO_BANDS, pairs=truth, seed=seed)
    images = {arc: dict(mocks.arc(arc)) for arc in ("L1", "L2")}
    psf = {band: np.asarray(mocks[("L1", band)].psf) for band in DEMO_BANDS}
    analysis = analyse(images, psf=psf, seed=seed)
    meta = mocks[("L1", DEMO_BANDS[0])].meta
    centre = SkyCoord(meta["LENSRA"] * u.deg, meta["LENSDEC"] * u.deg)
    rows = {}
    for method in ("adaptive", "quad2"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = (analysis.result if method == "adaptive" else
                   check_duality(analysis.result, method, sigma_pos=analysis.sigma_pos,
                                 n_bootstrap=1000, seed=seed))
        comp = compare_with_truth(res, truth, centre)
        sub = np.asarray(comp["subhalo"], dtype=bool)
        flagged = np.asarray(res["anomalous"], dtype=bool)
        tested = np.asarray(res["tested"], dtype=bool)
        rows[method] = {
            "n": len(res),
            "tested": int(tested.sum()),
            "clean_tested": int((tested & ~sub).sum()),
            "false": int((flagged & ~sub).sum()),
            "sub_flagged": bool((flagged & sub).any()) if sub.any() else None,
            "sub_snr": float(np.asarray(res["snr"])[sub][0]) if sub.any() else np.nan,
            "sub_sig": (float(np.asarray(res["significance"])[sub][0]) if sub.any()
                        else np.nan),
        }
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=0)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    totals = {}
    rec.say("seed subhalo method n tested false_flags subhalo_flagged subhalo_snr "
          "subhalo_significance")
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for subhalo in ("none", "overconcentrated"):
            for method, r in one(seed, subhalo).items():
                rec.say(f"{seed} {subhalo} {method} {r['n']} {r['tested']} {r['false']} "
                      f"{r['sub_flagged']} {r['sub_snr']:.1f} {r['sub_sig']:.1f}")
                t = totals.setdefault((subhalo, method), {"clean": 0, "false": 0, "hit": 0,
                                                          "runs": 0})
                t["clean"] += r["clean_tested"]
                t["false"] += r["false"]
                t["runs"] += 1
                t["hit"] += bool(r["sub_flagged"])
    rec.say("\nsubhalo method clean_pairs_tested false_flags rate subhalo_flagged_runs")
    for (subhalo, method), t in totals.items():
        hit = f"{t['hit']}/{t['runs']}" if subhalo != "none" else "-"
        rec.say(f"{subhalo} {method} {t['clean']} {t['false']} "
                f"{t['false'] / max(t['clean'], 1):.2%} {hit}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
