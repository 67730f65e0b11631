"""Accuracy of automatic pairing on random maps: the table of the "Pairing" docs page.

Run on demand (minutes)::

    python benchmarks/pairing_accuracy.py [--systems 200]

Each row pairs ``--systems`` random systems of ``make_system`` in
``tests/test_pairing.py`` (the last four rows half as many) and reports the
fraction of true pairs found, the fraction of systems without any wrong
pair, the most wrong pairs in one system and how many systems the pairing
refused (``ValueError``: no map, or not distinguishable from chance).
"""

import argparse
import sys
import time
import warnings

sys.path.insert(0, "tests")

from test_pairing import make_system, score  # noqa: E402

from lensdual.pairing import pair_constellations  # noqa: E402

CASES = [
    ("m = 12, sigma = 0.005\"", dict(m=12), 1.0),
    ("m = 6", dict(m=6), 1.0),
    ("m = 24", dict(m=24), 1.0),
    ("m = 12, noise-free", dict(m=12, noise=0.0), 1.0),
    ("m = 12, sigma = 0.01\"", dict(m=12, noise=0.01), 1.0),
    ("m = 12, sigma = 0.02\"", dict(m=12, noise=0.02), 1.0),
    ("m = 12, 35 % unmatched", dict(m=12, unmatched=0.35), 1.0),
    ("|det A| = 0.3, stretch 6-8", dict(det_range=(0.3, 0.3), stretch_range=(6, 8)), 0.5),
    ("|det A| = 3, stretch 6-8", dict(det_range=(3, 3), stretch_range=(6, 8)), 0.5),
    ("m = 16, quadratic distortion 2 %", dict(m=16, quad=0.02), 0.5),
    ("m = 16, quadratic distortion 5 %", dict(m=16, quad=0.05), 0.5),
]


def run_case(kwargs, n_systems):
    found = total = clean = max_wrong = refused = 0
    for seed in range(n_systems):
        c1, c2, truth, _ = make_system(seed, **kwargs)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = pair_constellations(c1, c2, id_column=None, seed=0)
            correct, wrong = score(result, truth)
        except ValueError:
            correct, wrong = 0, 0
            refused += 1
        found += correct
        total += len(truth)
        clean += wrong == 0
        max_wrong = max(max_wrong, wrong)
    return found / total, clean / n_systems, max_wrong, refused


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", type=int, default=200)
    args = parser.parse_args(argv)
    print(f"{'case':36s} {'systems':>7} {'found':>7} {'clean':>6} {'max wrong':>9} "
          f"{'refused':>7} {'time [s]':>8}")
    for name, kwargs, frac in CASES:
        n = max(1, int(round(frac * args.systems)))
        start = time.perf_counter()
        found, clean, max_wrong, refused = run_case(kwargs, n)
        print(f"{name:36s} {n:7d} {100 * found:6.1f}% {100 * clean:5.0f}% {max_wrong:9d} "
              f"{refused:7d} {time.perf_counter() - start:8.1f}", flush=True)


if __name__ == "__main__":
    main()
