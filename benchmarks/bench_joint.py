"""Speed of the joint duality test against the geometric one, in the same process.

Run on demand::

    python benchmarks/bench_joint.py [--output FILE]

For clean constellations of 20 and 40 sources (SMACS0723 analogue, 5 mas
position noise), the median wall time of ``check_duality`` with
``test="geometric"`` and ``test="joint"`` (both with the linearised SNR) and
with the defaults (the joint test with the conservative SNR) over repeated
calls, interleaved, after a warm-up call of each (Numba compilation), and
their ratios to the geometric test's. The joint test's target is at most 2x.
"""

import argparse
import time
import warnings

import numpy as np
from _output import Record, add_output_argument
from astropy import units as u

from lensdual.duality import check_duality
from lensdual.simulation import clean_constellation

SIGMA = 0.005


def _noisy(n, seed):
    t = clean_constellation("smacs_analog", n, seed=seed)
    rng = np.random.default_rng(seed)
    for col in ("x1", "y1", "x2", "y2"):
        t[col] = t[col] + SIGMA * rng.standard_normal(n) * u.arcsec
    return t


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    warnings.simplefilter("ignore")
    rec.say("n_sources geometric_ms joint_ms ratio default_ms default_ratio")
    settings = {"geometric": {"test": "geometric", "snr_definition": "log"},
                "joint": {"test": "joint", "snr_definition": "log"}, "default": {}}
    for n in (20, 40):
        t = _noisy(n, 1)
        times = {k: [] for k in settings}
        for kw in settings.values():
            check_duality(t, sigma_pos=SIGMA * u.arcsec, **kw)
        for _ in range(args.repeats):
            for key, kw in settings.items():
                t0 = time.perf_counter()
                check_duality(t, sigma_pos=SIGMA * u.arcsec, **kw)
                times[key].append(time.perf_counter() - t0)
        geo, joint, default = (1e3 * float(np.median(times[k])) for k in settings)
        rec.say(f"{n} {geo:.1f} {joint:.1f} {joint / geo:.2f} {default:.1f} "
                f"{default / geo:.2f}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
