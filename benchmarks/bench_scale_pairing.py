"""Scale of automatic pairing: true constellations buried in spurious candidates.

Run on demand (not part of the test suite)::

    python benchmarks/bench_scale_pairing.py [--spurious 0 100 300 500] [--seeds 3]

Each case is the ``make_system`` construction of ``tests/test_pairing.py``
(``--pairs`` true pairs related by a random affine map of either parity,
|det| 0.3-3, stretch 1-8, 5 mas position noise) plus ``--spurious``
candidates drawn uniformly over each arc's area (the bounding box of its
true points, widened by 10 %). Each run is a fresh interpreter, so that
its peak resident memory (``ru_maxrss``) is its own; the time is that of
:func:`~lensdual.pairing.pair_constellations` alone. Reported: time, peak
memory, true pairs found, wrong pairs.
"""

import argparse
import json
import subprocess
import sys
import textwrap

CHILD = textwrap.dedent("""
    import json, resource, sys, time
    import numpy as np
    from astropy import units as u
    sys.path.insert(0, "tests")
    from test_pairing import make_system
    from lensdual.pairing import pair_constellations

    seed, m, n_spur = (int(a) for a in sys.argv[1:4])
    c1, c2, truth, _ = make_system(seed, m=m, unmatched=0.0)
    rng = np.random.default_rng(10_000 + seed)
    cats = []
    for c in (c1.to_value(u.arcsec), c2.to_value(u.arcsec)):
        lo, hi = c.min(axis=0), c.max(axis=0)
        pad = 0.05 * (hi - lo)
        cats.append(np.vstack([c, rng.uniform(lo - pad, hi + pad, (n_spur, 2))]) * u.arcsec)
    start = time.perf_counter()
    try:
        res = pair_constellations(cats[0], cats[1], id_column=None, seed=0)
        found = dict(zip(np.asarray(res["id1"]).tolist(), np.asarray(res["id2"]).tolist()))
        error = None
    except ValueError as exc:
        found, error = {}, str(exc)[:80]
    elapsed = time.perf_counter() - start
    correct = sum(truth.get(k) == v for k, v in found.items())
    print(json.dumps({"seed": seed, "m": m, "spurious": n_spur, "time_s": elapsed,
                      "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "correct": correct, "true": len(truth),
                      "wrong": len(found) - correct, "error": error}))
""")


def run(seed, m, n_spur, timeout):
    try:
        out = subprocess.run([sys.executable, "-c", CHILD, str(seed), str(m), str(n_spur)],
                             capture_output=True, text=True, timeout=timeout, check=True)
    except subprocess.TimeoutExpired:
        return {"seed": seed, "m": m, "spurious": n_spur, "time_s": float("inf"),
                "peak_mb": float("nan"), "correct": 0, "true": m, "wrong": 0,
                "error": f"timeout {timeout} s"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spurious", type=int, nargs="+", default=[0, 100, 300, 500])
    parser.add_argument("--pairs", type=int, default=24)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=300.0)
    args = parser.parse_args(argv)
    print(f"{'spurious':>8} {'seed':>4} {'time [s]':>9} {'peak [MB]':>9} {'found':>7} "
          f"{'wrong':>5}  note")
    for n_spur in args.spurious:
        for seed in range(args.seeds):
            r = run(seed, args.pairs, n_spur, args.timeout)
            print(f"{n_spur:8d} {seed:4d} {r['time_s']:9.2f} {r['peak_mb']:9.0f} "
                  f"{r['correct']:3d}/{r['true']:<3d} {r['wrong']:5d}  {r['error'] or ''}",
                  flush=True)


if __name__ == "__main__":
    main()
