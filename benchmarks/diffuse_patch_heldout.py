"""The realistic scene's diffuse patch on lens families the demo is not.

Run on demand (about 20 s of CPU per seed and family)::

    python benchmarks/diffuse_patch_heldout.py [--seeds 16]
        [--families smacs_analog group_fold] [--output FILE]

The diffuse-light check and the patch (``MOCK_PATCH``: contrast 1, the
paper's pair 1, under pair 0's L2 image) were set on the demo's lens. Here
the same patch, with the scene's intracluster light and cluster member, is
rendered on other lenses and the whole pipeline runs (``analyse``, the
default test, no null calibration):

* ``smacs_analog``: the SMACS0723 analogue with
  ``acceptance_pixels.py``'s 12-source constellation;
* any family of :data:`lensdual.simulation.FAMILIES`: 12 sources of
  ``clean_constellation`` (at least 0.2 arcsec apart, so that detection and
  pairing find them, as in the demo).

There is no sub-halo. Reported per run: whether the patch pair was measured,
made doubtful, flagged, and flagged when the same measurements are tested
without the diffuse-light doubts; its flux-ratio error and ``t``; the other
pairs made doubtful, flagged, and tested. Then the totals per family.
"""

import argparse
import warnings

import numpy as np
from _output import Record, add_output_argument
from _scenes import flux_doubtful, patch_sources
from acceptance_pixels import grid_constellation
from astropy import units as u
from astropy.coordinates import SkyCoord

from lensdual.demo import compare_with_truth
from lensdual.duality import check_duality
from lensdual.exceptions import PipelineError
from lensdual.pipeline import analyse
from lensdual.simulation import render_mock_images, smacs0723_analog
from lensdual.simulation.families import calibration_system, clean_constellation

FAMILIES = ("smacs_analog", "group_fold")


def constellation(family, seed):
    """The lens system and the true pairs of one run."""
    if family == "smacs_analog":
        system = smacs0723_analog(seed=seed)
        return system, grid_constellation(system, np.random.default_rng(seed))
    system, _ = calibration_system(family)
    return system, clean_constellation(family, 12, seed=seed, min_separation=0.2 * u.arcsec)


def one(family, seed):
    """The tallies of one run, or the reason it could not run."""
    system, truth = constellation(family, seed)
    mocks = render_mock_images(system, pairs=truth, seed=seed, icl=True, member=True,
                               patch=True)
    images = {arc: mocks.arc(arc) for arc in ("L1", "L2")}
    try:
        analysis = analyse(images, sigma_pos="auto", seed=seed, null_realisations=0)
    except (PipelineError, ValueError) as err:  # too few pairs found, paired or kept
        return str(err).split(":")[0]
    res = analysis.result
    pairs = mocks.pairs.copy()
    pairs["mu_macro"] = pairs["mu_true"]  # no sub-halo
    pairs["subhalo"] = np.zeros(len(pairs), dtype=bool)
    meta = mocks[("L1", "F150W")].meta
    comp = compare_with_truth(res, pairs, SkyCoord(meta["LENSRA"] * u.deg,
                                                   meta["LENSDEC"] * u.deg))
    patch = np.isin(np.asarray(comp["source"]), patch_sources(pairs))
    doubtful = flux_doubtful(res)
    flag = np.asarray(res["anomalous"], dtype=bool)
    bare = res.copy()
    bare["flux_doubt"] = [""] * len(bare)
    without = np.asarray(check_duality(bare, "adaptive", sigma_pos=analysis.sigma_pos,
                                       seed=seed)["anomalous"], dtype=bool)
    t = np.asarray(res["diffuse_light_t"], dtype=float)
    k = np.flatnonzero(patch)
    return {
        "found": bool(k.size),
        "doubtful": bool((patch & doubtful).any()),
        "flagged": bool((patch & flag).any()),
        "flagged_without": bool((patch & without).any()),
        "error": float(np.asarray(comp["flux_error"], float)[k[0]]) if k.size else np.nan,
        "t": float(t[k[0]]) if k.size else np.nan,
        "other_doubtful": int((~patch & doubtful).sum()),
        "other_flagged": int((~patch & flag).sum()),
        "other_tested": int((~patch & np.asarray(res["tested"], bool)).sum()),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--families", nargs="+", default=list(FAMILIES))
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    rec.say("family seed: patch pair found, doubtful, flagged, flagged without the check, "
            "flux-ratio error, t; other pairs doubtful, flagged, tested")
    totals = {}
    for family in args.families:
        rows = []
        for seed in range(args.seeds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = one(family, seed)
            if isinstance(r, str):
                rec.say(f"{family} {seed}: not analysed ({r})")
                continue
            rows.append(r)
            rec.say(f"{family} {seed}: {r['found']:d} {r['doubtful']:d} {r['flagged']:d} "
                    f"{r['flagged_without']:d} {r['error']:+.3f} {r['t']:.1f}; "
                    f"{r['other_doubtful']} {r['other_flagged']} {r['other_tested']}")
        totals[family] = rows
    rec.say("\nfamily runs patch_found patch_doubtful patch_flagged patch_flagged_without "
            "median_patch_error other_doubtful other_flagged other_tested")
    for family, rows in totals.items():
        found = [r for r in rows if r["found"]]
        rec.say(f"{family} {len(rows)} {len(found)} {sum(r['doubtful'] for r in found)} "
                f"{sum(r['flagged'] for r in found)} "
                f"{sum(r['flagged_without'] for r in found)} "
                f"{np.nanmedian([r['error'] for r in found]) if found else np.nan:+.3f} "
                f"{sum(r['other_doubtful'] for r in rows)} "
                f"{sum(r['other_flagged'] for r in rows)} {sum(r['other_tested'] for r in rows)}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
