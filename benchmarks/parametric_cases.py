"""The (a)-(c) comparison of parametric fits with mu_size on the SMACS0723 analogue.

Run::

    python benchmarks/parametric_cases.py [--sigma-pos 0.06 0.01] [--n-starts 6]
        [--output docs/_static/parametric/cases.txt]

For each positional uncertainty ``sigma_pos`` and each case

(a) main halo only,
(b) main halo + the two cluster members of Table 1, not in the fitted model,
(c) main halo + the overconcentrated sub-halo on the L2 image of source 0,

it simulates ``smacs0723_analog(seed=1)`` (16 sources), takes the noiseless
constellation (``constellation(seed=1)``: positions exact, fluxes
``|mu_true| x intrinsic`` with 2 % errors), runs
``check_duality(pairs, sigma_pos=sigma_pos, seed=1)`` and fits
``NFW_ELLIPSE_CSE + SHEAR`` with the halo centre fixed at (0, 0)
(``fit_parametric_lens(..., sigma_pos=sigma_pos, n_starts=6, seed=1)``), then
prints one row of the table of ``docs/parametric_fits.rst``: chi2 / dof, the
median and maximum of ``|mu / mu_true - 1|`` for ``mu_size`` and
``mu_model``, the median relative errors ``err / value``, the pairs flagged
(SNR > 3) against each, and the fit time; below each row, the worst pairs, the
SNRs of pair 1 and the best fit, then the Laplace 1-sigma half-widths of the
free parameters with their bounds and the fraction of the 300 parameter draws
``compare_with_parametric`` uses (the Laplace draws clipped to the bounds) that
sit on a bound, per parameter. Everything is seeded: the numbers are
reproducible (the fit time is not). ``docs/scripts/parametric_numbers.py``
turns the stored output of ``--output`` into the page's tables and numbers.
"""

import argparse
import time
import warnings

import numpy as np
from _output import Record, add_output_argument
from astropy import units as u

from lensdual.duality import check_duality
from lensdual.parametric import compare_with_parametric, fit_parametric_lens
from lensdual.simulation import smacs0723_analog

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

CASES = {
    "(a) main halo only": {},
    "(b) + 2 cluster members, not in the model": {"perturbers": True},
    "(c) + overconcentrated sub-halo on pair 1 (L2)": {"subhalo": "overconcentrated"},
}
FIXED_CENTRE = {"NFW_ELLIPSE_CSE": {"center_x": 0.0, "center_y": 0.0}}
#: The parameter draws of ``compare_with_parametric`` (its ``n_samples``).
N_DRAWS = 300


def run_case(kwargs, sigma_pos, n_starts):
    """One row of the table: a dict of the numbers."""
    system = smacs0723_analog(seed=1, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pairs = system.constellation(seed=1)
    duality = check_duality(pairs, sigma_pos=sigma_pos, seed=1, **GEOMETRIC)
    start = time.perf_counter()
    fit = fit_parametric_lens(pairs, model=("NFW_ELLIPSE_CSE", "SHEAR"), z_lens=system.z_lens,
                              z_source=system.z_source, sigma_pos=sigma_pos,
                              fixed_params=FIXED_CENTRE, n_starts=n_starts, seed=1)
    elapsed = time.perf_counter() - start
    table = compare_with_parametric(duality, fit, seed=1)
    truth = np.asarray(table["mu_true"], float)
    row = {"chi2": fit.chi2, "dof": fit.dof, "time": elapsed, "n_pairs": len(table)}
    for key in ("size", "model"):
        mu = np.asarray(table[f"mu_{key}"], float)
        dev = np.abs(mu / truth - 1.0)
        row[f"{key}_median"] = float(np.median(dev))
        row[f"{key}_max"] = float(np.max(dev))
        row[f"{key}_worst"] = int(np.asarray(table["pair_id"])[np.argmax(dev)])
        row[f"{key}_relerr"] = float(np.median(np.asarray(table[f"mu_{key}_err"], float) / mu))
        flagged = np.asarray(table["pair_id"])[np.asarray(table[f"anomalous_{key}"], bool)]
        row[f"{key}_flagged"] = flagged.tolist()
        row[f"{key}_snr_pair1"] = float(np.asarray(table[f"snr_{key}"], float)[0])
    row["best_params"] = fit.best_params
    # the draws of compare_with_parametric: n_samples=300 from a generator seeded 1
    draws = fit._param_sample(N_DRAWS, np.random.default_rng(1))
    lower, upper = fit._param.lower, fit._param.upper
    on_bound = np.mean((draws <= lower) | (draws >= upper), axis=0)
    half = np.sqrt(np.diag(fit.covariance))
    row["spread"] = {name.split(".")[-1]: (h, lo, hi, f)
                     for name, h, lo, hi, f in zip(fit.param_names, half, lower, upper, on_bound,
                                                   strict=True)}
    return row


def _pct(value):
    if value < 1e-6:
        return f"{value:.0e}"
    return f"{100 * value:.2g} %" if value < 0.1 else f"{100 * value:.3g} %"


def _flags(ids):
    return "none" if not ids else ", ".join(str(i) for i in ids)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sigma-pos", type=float, nargs="+", default=[0.06, 0.01],
                        help="positional uncertainties in arcsec (default 0.06 0.01)")
    parser.add_argument("--n-starts", type=int, default=6)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    record = Record()
    for sig in args.sigma_pos:
        sigma_pos = sig * u.arcsec
        record.say(f"\nsigma_pos = {sig} arcsec")
        header = (f"{'case':48s}  {'chi2 / dof':>12s}  {'mu_size dev med / max':>22s}  "
                  f"{'mu_model dev med / max':>22s}  {'rel. err size / model':>21s}  "
                  f"{'flagged size / model':>20s}  {'time':>6s}")
        record.say(header)
        for name, kwargs in CASES.items():
            r = run_case(kwargs, sigma_pos, args.n_starts)
            record.say(f"{name:48s}  {r['chi2']:.2g} / {r['dof']:<4d}  "
                       f"{_pct(r['size_median']):>9s} / {_pct(r['size_max']):<10s}  "
                       f"{_pct(r['model_median']):>9s} / {_pct(r['model_max']):<10s}  "
                       f"{r['size_relerr']:>9.2g} / {r['model_relerr']:<9.2g}  "
                       f"{_flags(r['size_flagged']):>9s} / {_flags(r['model_flagged']):<9s}  "
                       f"{r['time']:5.0f} s")
            record.say(f"    worst pair: size {r['size_worst']}, model {r['model_worst']}; "
                       f"SNR of pair 1: size {r['size_snr_pair1']:.2g}, model "
                       f"{r['model_snr_pair1']:.2g}; best fit: "
                       + ", ".join(f"{k}={v:.4g}" for k, v in r["best_params"].items()))
            record.say("    Laplace 1-sigma (fitted space) [bounds], draws on a bound: "
                       + ", ".join(f"{k} +-{h:.2g} [{lo:.3g}, {hi:.3g}] {100 * f:.0f} %"
                                   for k, (h, lo, hi, f) in r["spread"].items()))
    record.write(args.output)


if __name__ == "__main__":
    main()
