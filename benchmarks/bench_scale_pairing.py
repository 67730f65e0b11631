"""Scale of automatic pairing: true constellations buried in spurious candidates.

Run on demand (not part of the test suite)::

    python benchmarks/bench_scale_pairing.py [--spurious 0 100 300 500] [--seeds 3]
        [--fluxes with|without|both] [--output FILE]

Each case is ``crowded_system`` of ``tests/test_pairing.py``: the
``make_system`` construction (``--pairs`` true pairs related by a random
affine map of either parity, |det| 0.3-3, stretch 1-8, 5 mas position
noise) plus ``--spurious`` candidates drawn uniformly over each arc's area
(the bounding box of its true points, widened by 10 %), with fluxes in two
bands (true sources bright and of consistent colour, spurious ones faint,
near the detection threshold, of random colour; see its docstring). The
pairing is run without fluxes and with them (``flux_columns``). Each run
is a fresh interpreter, so that its peak resident memory (``ru_maxrss``)
is its own; the time is that of :func:`~lensdual.pairing.pair_constellations`
alone. Reported: time, peak memory, true pairs found, wrong pairs, and the
start of the error message when the pairing refuses.
"""

import argparse
import json
import subprocess
import sys
import textwrap

from _output import Record, add_output_argument

CHILD = textwrap.dedent("""
    import json, resource, sys, time
    import numpy as np
    sys.path.insert(0, "tests")
    from test_pairing import crowded_system
    from lensdual.pairing import pair_constellations

    seed, m, n_spur, fluxes = (int(a) for a in sys.argv[1:5])
    cat1, cat2, truth = crowded_system(seed, n_spur, m=m)
    start = time.perf_counter()
    try:
        res = pair_constellations(cat1, cat2, id_column=None, seed=0,
                                  flux_columns=["f1", "f2"] if fluxes else None)
        found = dict(zip(np.asarray(res["id1"]).tolist(), np.asarray(res["id2"]).tolist()))
        error = None
    except ValueError as exc:
        found, error = {}, str(exc)[:60]
    elapsed = time.perf_counter() - start
    correct = sum(truth.get(k) == v for k, v in found.items())
    print(json.dumps({"seed": seed, "m": m, "spurious": n_spur, "time_s": elapsed,
                      "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "correct": correct, "true": len(truth),
                      "wrong": len(found) - correct, "error": error}))
""")


def run(seed, m, n_spur, fluxes, timeout):
    try:
        out = subprocess.run([sys.executable, "-c", CHILD, str(seed), str(m), str(n_spur),
                              str(int(fluxes))],
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
    parser.add_argument("--fluxes", choices=["with", "without", "both"], default="both",
                        help="give flux_columns (two bands) to the pairing")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    modes = {"with": [True], "without": [False], "both": [False, True]}[args.fluxes]
    rec.say(f"{'fluxes':>6} {'spurious':>8} {'seed':>4} {'time [s]':>9} {'peak [MB]':>9} "
            f"{'found':>7} {'wrong':>5}  note")
    for fluxes in modes:
        for n_spur in args.spurious:
            for seed in range(args.seeds):
                r = run(seed, args.pairs, n_spur, fluxes, args.timeout)
                rec.say(f"{'yes' if fluxes else 'no':>6} {n_spur:8d} {seed:4d} "
                        f"{r['time_s']:9.2f} {r['peak_mb']:9.0f} "
                        f"{r['correct']:3d}/{r['true']:<3d} {r['wrong']:5d}  "
                        f"{r['error'] or ''}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
