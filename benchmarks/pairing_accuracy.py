"""Accuracy of automatic pairing on random maps: the tables of the "Pairing" docs page.

Run on demand (about five minutes on one core)::

    python benchmarks/pairing_accuracy.py [--systems 200] [--smacs-seeds 50]
        [--output docs/_static/pairing/accuracy.txt]

The first table starts with the median nearest-neighbour distance of the
catalogues on L2 (the scale of the position noise). Each of its rows pairs
``--systems`` random systems of ``make_system`` in ``tests/test_pairing.py``
(the last four rows half as many) and reports the points per catalogue (of
the first system), the fraction of true pairs found, the fraction of systems
without any wrong pair, the most wrong pairs in one system, how many systems
the pairing refused (``ValueError``: no map, or not distinguishable from
chance) and the mean time per system (after one untimed pairing that loads
the compiled kernels). Every refused system is then paired once more with
the decoy check switched off, which says what the refusal kept out.

The second table pairs the SMACS0723 analogue (``smacs_catalogues`` of
``tests/test_pairing.py``: seeds 0 to ``--smacs-seeds`` - 1, two images lost
and two spurious detections on each arc, shuffled) with Gaussian position
noise on both arcs, and with the F150W/F200W colours in the last row. Both
tables count the systems where the pairing chose the quadratic map. The
analogue's line above its table gives its median ``|det A|``, its
nearest-neighbour distances and how far it is from affine.

Last, chance alignments: how many pairs the search returns on two unrelated
catalogues (L1 of one random system, L2 of another) with the decoy check
switched off, for 8, 15 and 30 points per catalogue.

``docs/scripts/pairing_numbers.py`` turns the output of ``--output`` into the
page's tables and numbers.
"""

import argparse
import sys
import time
import warnings

import astropy.units as u
import numpy as np
from _output import Record, add_output_argument
from scipy.spatial import cKDTree

sys.path.insert(0, "tests")

from test_pairing import make_system, score, smacs_catalogues  # noqa: E402

from lensdual import pairing  # noqa: E402
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
#: Rows of the SMACS0723 analogue: label, position noise (mas), colours.
SMACS_CASES = [("none", 0.0, False), ("1 mas", 1.0, False), ("2 mas", 2.0, False),
               ("2 mas, with F150W/F200W colours", 2.0, True)]
#: The analogue's flux columns.
SMACS_FLUXES = ["flux_F150W", "flux_F200W"]
#: Sources per catalogue of the unrelated catalogues (``make_system``'s ``m``),
#: and the seed offset of the second catalogue.
UNRELATED = (6, 12, 24)
UNRELATED_OFFSET = 10_000


def _pair(c1, c2, truth, **kwargs):
    """(correct, wrong, refused, map order) of one automatic pairing."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = pair_constellations(c1, c2, **kwargs)
    except ValueError:
        return 0, 0, True, None
    return (*score(result, truth), False, result.meta["map"]["order"])


def _unguarded(c1, c2, truth, **kwargs):
    """``_pair`` with the decoy check switched off."""
    margin = pairing._DECOY_MARGIN
    pairing._DECOY_MARGIN = 0.0
    try:
        return _pair(c1, c2, truth, **kwargs)
    finally:
        pairing._DECOY_MARGIN = margin


def _without_guard(c1, c2, truth, **kwargs):
    """What the pairing gives with the decoy check switched off, in words."""
    correct, wrong, refused, _ = _unguarded(c1, c2, truth, **kwargs)
    return "refused" if refused else f"{correct} of {len(truth)} right, {wrong} wrong"


class Tally:
    """Found, clean, most wrong and refused over the systems of one row."""

    def __init__(self):
        self.found = self.total = self.clean = self.max_wrong = self.n = 0
        self.quadratic = 0
        self.refused = []
        self.start = time.perf_counter()

    def add(self, correct, wrong, refused, order, n_true, seed):
        self.n += 1
        self.found += correct
        self.total += n_true
        self.clean += wrong == 0
        self.max_wrong = max(self.max_wrong, wrong)
        self.quadratic += order == 2
        if refused:
            self.refused.append(seed)

    def row(self, name, points=None):
        per = 1e3 * (time.perf_counter() - self.start) / self.n
        points = "" if points is None else f"{points:>8}"
        return (f"{name:36s} {self.n:7d}{points} {100 * self.found / self.total:6.1f}% "
                f"{100 * self.clean / self.n:5.0f}% {self.max_wrong:9d} "
                f"{len(self.refused):7d} {self.quadratic:9d} {per:10.0f}")


def median_separation(n_systems):
    """Median over systems of the median nearest-neighbour distance on L2 (arcsec), m = 12."""
    medians = []
    for seed in range(n_systems):
        c2 = make_system(seed)[1].to_value(u.arcsec)
        medians.append(np.median(cKDTree(c2).query(c2, k=2)[0][:, 1]))
    return float(np.median(medians))


def random_maps(n_systems, say):
    """The first table: random maps of ``make_system``."""
    say(f"median nearest-neighbour distance on L2 (m = 12): "
        f"{median_separation(n_systems):.3f} arcsec")
    say(f"{'case':36s} {'systems':>7} {'points':>7} {'found':>7} {'clean':>6} "
        f"{'max wrong':>9} {'refused':>7} {'quadratic':>9} {'ms/system':>10}")
    c1, c2, truth, _ = make_system(0)
    _pair(c1, c2, truth, id_column=None, seed=0)  # imports and compiled kernels, untimed
    refused = []
    for name, kwargs, frac in CASES:
        tally = Tally()
        for seed in range(max(1, int(round(frac * n_systems)))):
            c1, c2, truth, _ = make_system(seed, **kwargs)
            if seed == 0:
                points = f"{len(c1)} + {len(c2)}"
            tally.add(*_pair(c1, c2, truth, id_column=None, seed=0), len(truth), seed)
        say(tally.row(name, points))
        refused += [(name, kwargs, seed) for seed in tally.refused]
    for name, kwargs, seed in refused:
        c1, c2, truth, _ = make_system(seed, **kwargs)
        say(f"refused: {name}, seed {seed}; without the decoy check "
            f"{_without_guard(c1, c2, truth, id_column=None, seed=0)}")


def _noisy(table, noise, rng):
    """A copy of a catalogue with Gaussian noise of ``noise`` mas on both coordinates."""
    table = table.copy()
    for col in ("x", "y"):
        table[col] = table[col] + rng.normal(scale=noise, size=len(table)) * u.mas
    return table


def _affine_residual(pairs):
    """Largest residual (arcsec) of the least-squares affine map from L2 to L1 of the true pairs."""
    x1 = np.column_stack([pairs["x1"].to_value(u.arcsec), pairs["y1"].to_value(u.arcsec)])
    x2 = np.column_stack([pairs["x2"].to_value(u.arcsec), pairs["y2"].to_value(u.arcsec)])
    design = np.column_stack([x2, np.ones(len(x2))])
    coef = np.linalg.lstsq(design, x1, rcond=None)[0]
    return float(np.max(np.hypot(*(x1 - design @ coef).T)))


def smacs_analogue(n_seeds, say):
    """The second table: the SMACS0723 analogue with position noise and colours."""
    systems, det, nn, residual = [], [], [], []
    for seed in range(n_seeds):
        c1, c2, truth, pairs = smacs_catalogues(seed)
        systems.append((c1, c2, truth))
        det.extend(np.asarray(pairs["mu_true"]))
        x2 = np.column_stack([pairs["x2"].to_value(u.arcsec), pairs["y2"].to_value(u.arcsec)])
        nn.append(cKDTree(x2).query(x2, k=2)[0][:, 1])
        residual.append(_affine_residual(pairs))
    c1, c2, truth = systems[0]
    say(f"SMACS0723 analogue, seeds 0-{n_seeds - 1}: {len(truth)} true pairs among "
        f"{len(c1)} + {len(c2)} points")
    say(f"  median |det A| (mu_true) {np.median(det):.2f}; nearest-neighbour distance on L2: "
        f"median {np.median([np.median(d) for d in nn]):.3f} arcsec, smallest "
        f"{np.min(np.concatenate(nn)):.4f} arcsec; largest residual of an affine map "
        f"fitted to the true pairs {max(residual):.3f} arcsec")
    say(f"{'position noise':36s} {'systems':>7} {'found':>7} {'clean':>6} "
        f"{'max wrong':>9} {'refused':>7} {'quadratic':>9} {'ms/system':>10}")
    for name, noise, colours in SMACS_CASES:
        tally = Tally()
        for seed, (c1, c2, truth) in enumerate(systems):
            rng = np.random.default_rng(seed)
            c1, c2 = _noisy(c1, noise, rng), _noisy(c2, noise, rng)
            kwargs = {"flux_columns": SMACS_FLUXES} if colours else {}
            tally.add(*_pair(c1, c2, truth, **kwargs), len(truth), seed)
        say(tally.row(name))


def unrelated(n_seeds, say):
    """Chance alignments: pairs the search returns on two unrelated catalogues
    (L1 of one random system, L2 of another) with the decoy check switched off."""
    for m in UNRELATED:
        counts = []
        for seed in range(n_seeds):
            c1 = make_system(seed, m=m)[0]
            c2 = make_system(UNRELATED_OFFSET + seed, m=m)[1]
            correct, wrong, refused, _ = _unguarded(c1, c2, {}, id_column=None, seed=0)
            counts.append(0 if refused else wrong)
        say(f"unrelated catalogues, {len(c1)} + {len(c2)} points, {n_seeds} seeds, without "
            f"the decoy check: {min(counts)}-{max(counts)} pairs")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", type=int, default=200,
                        help="systems per row of the random maps (default 200)")
    parser.add_argument("--smacs-seeds", type=int, default=50,
                        help="seeds of the SMACS0723 analogue (default 50)")
    parser.add_argument("--unrelated-seeds", type=int, default=20,
                        help="pairs of unrelated catalogues per size (default 20)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    record = Record()
    random_maps(args.systems, record.say)
    smacs_analogue(args.smacs_seeds, record.say)
    unrelated(args.unrelated_seeds, record.say)
    record.write(args.output)


if __name__ == "__main__":
    main()
