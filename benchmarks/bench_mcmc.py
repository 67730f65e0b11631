"""Cost and convergence of the emcee posterior of a parametric fit.

Run on demand (about a minute)::

    python benchmarks/bench_mcmc.py [--output FILE]

The lens and constellation of ``tests/test_fitting.py`` (SIE + external
shear, 16 noiseless pairs on a fold pair of arcs, the SIE centre fixed, 5
free parameters, 10 walkers):

* ``sigma_pos = 0.005 arcsec``, ``n_mcmc = 40000`` (the page's example):
  the largest integrated autocorrelation time and the kept steps in units
  of it;
* ``sigma_pos = 0.06 arcsec``, ``n_mcmc = 40000``: the same, and the cost
  of the chain, the fit's time with ``mcmc=True`` minus without, also per
  evaluation of the posterior (``n_mcmc`` of them).

With ``--output FILE`` the figures also go to FILE: ``docs/parametric_fits.rst``
quotes ``docs/_static/parametric/mcmc.txt`` through
``docs/scripts/parametric_numbers.py``.
"""

import argparse
import time
import warnings

import numpy as np
from _output import Record, add_output_argument
from astropy import units as u

from lensdual.parametric.fitting import fit_parametric_lens
from lensdual.simulation import LensComponent, LensSystem

TRUTH = [
    {"theta_E": 1.5, "e1": 0.1, "e2": -0.05, "center_x": 0.0, "center_y": 0.0},
    {"gamma1": 0.04, "gamma2": 0.02, "ra_0": 0.0, "dec_0": 0.0},
]
ZL, ZS = 0.5, 2.0
KW = {"model": ("SIE", "SHEAR"), "z_lens": ZL, "z_source": ZS, "seed": 1,
      "fixed_params": {"SIE": {"center_x": 0.0, "center_y": 0.0}}}
#: (sigma_pos in arcsec, n_mcmc) of each run.
RUNS = ((0.005, 40000), (0.06, 40000))


def test_pairs():
    """The 16 noiseless pairs of tests/test_fitting.py."""
    system = LensSystem([LensComponent("SIE", TRUTH[0]), LensComponent("SHEAR", TRUTH[1])],
                        z_lens=ZL, z_source=ZS)
    rng = np.random.default_rng(3)
    beta = (np.array([0.0, 0.25]) + rng.uniform(-0.06, 0.06, (16, 2))) * u.arcsec
    return system.constellation(beta, half_width=4 * u.arcsec, grid_spacing=0.1 * u.arcsec,
                                seed=1)


def timed_fit(pairs, **kwargs):
    """The fit and its wall time (s)."""
    start = time.perf_counter()
    fit = fit_parametric_lens(pairs, **KW, **kwargs)
    return fit, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    warnings.simplefilter("ignore")
    pairs = test_pairs()
    timed_fit(pairs, sigma_pos=0.06 * u.arcsec, mcmc=True, n_mcmc=400)  # compile, warm up
    rec.say(f"SIE + shear of tests/test_fitting.py, {len(pairs)} pairs")
    for sigma, n_mcmc in RUNS:
        fit, with_mcmc = timed_fit(pairs, sigma_pos=sigma * u.arcsec, mcmc=True, n_mcmc=n_mcmc)
        _, without = timed_fit(pairs, sigma_pos=sigma * u.arcsec)
        info = fit.mcmc_info
        tau = max(info["autocorr_time"].values())
        chain = with_mcmc - without
        rec.say(f"sigma_pos = {sigma:g} arcsec, n_mcmc = {n_mcmc}: {info['n_walkers']} walkers "
                f"x {info['n_steps']} steps, {info['burn_in']} burn-in; largest tau "
                f"{tau:.0f} steps, kept steps / tau {info['n_autocorr']:.0f}; chain "
                f"{chain:.1f} s, {1e3 * chain / n_mcmc:.2f} ms per evaluation")
    rec.write(args.output)


if __name__ == "__main__":
    main()
