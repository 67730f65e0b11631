"""The flux-ratio pulls of the whole pipeline on the demo's point and realistic scenes.

Run on demand (about 12 s of CPU per seed and scene)::

    python benchmarks/scene_flux_pulls.py [--seeds 30] [--scenes point realistic]
        [--output FILE]

For every seed, the demo's lens without a sub-halo is rendered as ``lensdual
demo`` does (``--scene point`` or ``--scene realistic``: clusters of 1-50
pc, host clumps, a member, the intracluster light, the diffuse patch under
pair 0's L2 image, poppy's spiked PSF) and runs through the pipeline
(``analyse``, no null calibration). Each measured pair matched to a true
one, the patch pair apart, gives the pull of its flux ratio,
``ln(mu_flux / mu_true) / (mu_flux_err / mu_flux)``. Reported per scene: the
pairs, the median pull, the 16-84 % half-width, the standard deviation, and
the fraction beyond 3 in either direction (0.27 % for a standard normal).
"""

import argparse
import warnings

import numpy as np
from _output import Record, add_output_argument
from _scenes import patch_sources

from lensdual.demo import compare_with_truth, render_demo, simulate_demo
from lensdual.pipeline import analyse


def pulls(scene, seed):
    """The flux-ratio pulls of one render."""
    system, truth = simulate_demo(seed=seed, subhalo="none")
    demo = render_demo(system, truth, seed=seed, scene=scene)
    res = analyse(demo.images, psf=demo.psf, sigma_pos="auto", seed=seed,
                  null_realisations=0).result
    comp = compare_with_truth(res, truth, demo.centre)
    pairs = demo.mocks.pairs
    under = patch_sources(pairs)
    source = np.asarray(comp["source"])
    keep = (source >= 0) & ~np.isin(source, under)
    mu_flux = np.asarray(res["mu_flux"], dtype=float)
    pull = (np.log(mu_flux / np.asarray(comp["mu_true"], dtype=float))
            / (np.asarray(res["mu_flux_err"], dtype=float) / mu_flux))
    return pull[keep & np.isfinite(pull)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--scenes", nargs="+", default=["point", "realistic"])
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    rec.say(f"flux-ratio pulls, the demo without a sub-halo, seeds 0-{args.seeds - 1}")
    rec.say("scene pairs median half_width_16_84 std beyond_3_percent")
    for scene in args.scenes:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            p = np.concatenate([pulls(scene, seed) for seed in range(args.seeds)])
        q16, q50, q84 = np.percentile(p, [16, 50, 84])
        rec.say(f"{scene} {p.size} {q50:+.2f} {(q84 - q16) / 2:.2f} {p.std():.2f} "
                f"{100 * np.mean(np.abs(p) > 3):.1f}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
