"""The realistic scene under the default test and under the former default.

Run on demand (about 20 s per seed on 2 cores)::

    python benchmarks/scene_default_test.py [--seeds 30] [--subhalo none] [--output FILE]

For every seed, ``lensdual demo --scene realistic`` (the demo's lens and over-
concentrated sub-halo, or with ``--subhalo none`` no sub-halo; clusters of
1-50 pc, host clumps, a member, the intracluster light, a diffuse patch under
pair 0's L2 image, poppy's spiked PSF; PSF photometry of point sources) runs
through the pipeline without its null calibration, and the measured pairs are
tested twice: by the default test (``test="auto"``, ``snr_definition="auto"``:
the joint test with the conservative SNR, which falls back on the geometry
where the flux field has too few neighbours) and by the geometric test with
the linearised SNR (the default when ``benchmarks/finite_size_bias.py``'s
record was made). Reported per seed and test: the clean pairs tested and
flagged (the patch pair and the sub-haloed pair apart), whether the patch pair
and the sub-haloed pair were flagged; then the totals and the seeds where the
two tests differ. Then, per seed, the pipeline's diffuse-light doubts (the
same for both tests): the clean pairs, the patch pair and the sub-haloed pair
whose flux ratio was doubtful because the light under their two images differs
(``flux_doubt``).
"""

import argparse
import warnings

import numpy as np
from _output import Record, add_output_argument
from _scenes import flux_doubtful, patch_sources

from lensdual.demo import compare_with_truth, render_demo, simulate_demo
from lensdual.duality import check_duality
from lensdual.pipeline import analyse

#: The tests compared: the default, and the former default.
TESTS = {"default": {}, "geometric_log": {"test": "geometric", "snr_definition": "log"}}


def one(seed, subhalo="overconcentrated"):
    """``{test: (clean tested, clean flagged, patch flagged, sub-halo flagged)}`` and the
    diffuse-light doubts ``(clean, patch, sub-halo)``."""
    system, truth = simulate_demo(seed=seed, subhalo=subhalo)
    demo = render_demo(system, truth, seed=seed, scene="realistic")
    analysis = analyse(demo.images, psf=demo.psf, sigma_pos="auto", seed=seed,
                       null_realisations=0)
    pairs = demo.mocks.pairs
    under = patch_sources(pairs)
    out = {}
    for name, kw in TESTS.items():
        res = (analysis.result if not kw else
               check_duality(analysis.result, "adaptive", sigma_pos=analysis.sigma_pos,
                             seed=seed, **kw))
        comp = compare_with_truth(res, truth, demo.centre)
        sub = np.asarray(comp["subhalo"], dtype=bool)
        flag = np.asarray(comp["anomalous"], dtype=bool)
        patch = np.isin(np.asarray(comp["source"]), under) & ~sub
        clean = ~sub & ~patch
        tested = np.asarray(res["tested"], dtype=bool)
        out[name] = (int((clean & tested).sum()), int((clean & flag).sum()),
                     bool((patch & flag).any()), bool((sub & flag).any()))
        diffuse = flux_doubtful(res)
        doubts = (int((clean & diffuse).sum()), bool((patch & diffuse).any()),
                  bool((sub & diffuse).any()))
    return out, doubts


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--subhalo", default="overconcentrated",
                        choices=("overconcentrated", "none"),
                        help="the demo's sub-halo, or none (every pair but the patch's clean)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    rec.say("seed test clean_tested clean_flagged patch_flagged subhalo_flagged")
    totals = {name: np.zeros(4, dtype=int) for name in TESTS}
    differ = []
    doubts = []
    for seed in range(args.seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows, doubt = one(seed, args.subhalo)
        doubts.append(doubt)
        for name, row in rows.items():
            rec.say(f"{seed} {name} {row[0]} {row[1]} {row[2]} {row[3]}")
            totals[name] += np.array(row, dtype=int)
        if len(set(rows.values())) > 1:
            differ.append(seed)
    rec.say("\ntest clean_tested clean_flagged patch_flagged_seeds subhalo_flagged_seeds seeds")
    for name, t in totals.items():
        rec.say(f"{name} {t[0]} {t[1]} {t[2]} {t[3]} {args.seeds}")
    rec.say(f"seeds where the two tests differ: {len(differ)}"
            + (f" ({', '.join(map(str, differ))})" if differ else ""))
    rec.say("\ndiffuse-light doubts per seed: seed clean_doubtful patch_doubtful "
            "subhalo_doubtful")
    for seed, (c, p, s) in enumerate(doubts):
        rec.say(f"{seed} {c} {p} {s}")
    d = np.array(doubts, dtype=int)
    rec.say(f"diffuse-light doubts: clean {d[:, 0].sum()} patch {d[:, 1].sum()} "
            f"subhalo {d[:, 2].sum()} seeds {args.seeds}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
