"""What the neighbour cap changes, on the smooth test map of tests/test_estimators.py.

Run on demand (about a minute)::

    python benchmarks/neighbour_cap.py [--output FILE]

The setups of the tests of the cap (``nonlinear_map`` and its exact
``|det J|``, 2000 pairs uniform over +-1.5 arcsec, seed 0):

* without noise, ``relative_jacobian`` with the default cap
  (``max_neighbours=64``) and without (``max_neighbours=None``): the largest
  relative error of ``|det J|`` against the exact one, per method;
* with 2 mas position noise on both arcs, the adaptive estimator on the first
  200 pairs, capped and uncapped: how many pairs get the same estimate, the
  difference of ``ln mu_size`` over the
  two errors added in quadrature (median and 90th percentile), the ratio of
  the errors at the median, and the 16-84 % range of the pulls against the
  exact ``mu``; on all 2000 pairs, capped: the pulls' 16-84 % half-width and
  the fraction beyond 3 sigma.

With ``--output FILE`` the figures also go to FILE: ``docs/performance.rst``
quotes ``docs/_static/performance/neighbour_cap.txt`` through
``docs/scripts/performance_numbers.py``.
"""

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
from astropy import units as u

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from _output import Record, add_output_argument  # noqa: E402
from test_estimators import _exact_mu, nonlinear_map  # noqa: E402

from lensdual.estimators import relative_jacobian, size_magnification  # noqa: E402

N_PAIRS = 2000
N_COMPARED = 200
SIGMA = 0.002  # arcsec


def _mu(jac):
    return np.abs(np.linalg.det(jac))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    warnings.simplefilter("ignore")
    rng = np.random.default_rng(0)
    t2 = rng.uniform(-1.5, 1.5, (N_PAIRS, 2))
    t1 = nonlinear_map(t2)
    mu = _exact_mu(t2)

    rec.say(f"{N_PAIRS} pairs of the smooth test map, no noise: largest |mu / mu_exact - 1|")
    rec.say(f"{'method':<8}{'capped':>10}{'uncapped':>10}")
    for method in ("2v", "quad", "quad2"):
        errors = []
        for cap in (64, None):
            jac = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method, max_neighbours=cap)
            errors.append(np.max(np.abs(_mu(jac) / mu - 1)))
        rec.say(f"{method:<8}{100 * errors[0]:>9.2f}%{100 * errors[1]:>9.2f}%")

    o1 = t1 + SIGMA * rng.standard_normal(t1.shape)
    o2 = t2 + SIGMA * rng.standard_normal(t2.shape)
    kw = {"sigma_pos": SIGMA * u.arcsec}
    sub = slice(0, N_COMPARED)
    tabs = {cap: size_magnification(o1[sub] * u.arcsec, o2[sub] * u.arcsec,
                                    max_neighbours=cap, **kw) for cap in (64, None)}
    ln = {cap: np.log(np.asarray(t["mu_size"])) for cap, t in tabs.items()}
    err = {cap: np.asarray(t["ln_mu_size_err"]) for cap, t in tabs.items()}
    z = np.abs(ln[64] - ln[None]) / np.hypot(err[64], err[None])
    rec.say(f"adaptive, {N_COMPARED} pairs, {1e3 * SIGMA:g} mas noise, capped against uncapped:")
    same = int(np.sum(np.abs(ln[64] - ln[None]) <= 1e-9 * err[64]))
    rec.say(f"  the same estimate (within 1e-9 of the error): {same} of {N_COMPARED} pairs")
    rec.say(f"  |difference of ln mu_size| / errors in quadrature: median {np.median(z):.2g}, "
            f"90th percentile {np.percentile(z, 90):.2f}")
    rec.say(f"  error capped / uncapped: median {np.median(err[64] / err[None]):.3f}")
    for cap, label in ((64, "capped"), (None, "uncapped")):
        pull = (ln[cap] - np.log(mu[sub])) / err[cap]
        q16, q84 = np.percentile(pull, [15.87, 84.13])
        rec.say(f"  pulls against the exact mu, {label}: 16-84 % {q16:.2f} to {q84:.2f}")

    tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, **kw)
    pull = np.log(np.asarray(tab["mu_size"]) / mu) / np.asarray(tab["ln_mu_size_err"])
    q16, q84 = np.percentile(pull, [15.87, 84.13])
    rec.say(f"adaptive, {N_PAIRS} pairs, capped: pull width (16-84 % half-width) "
            f"{0.5 * (q84 - q16):.2f}, beyond 3 sigma {100 * np.mean(np.abs(pull) > 3):.2f} %")
    rec.write(args.output)


if __name__ == "__main__":
    main()
