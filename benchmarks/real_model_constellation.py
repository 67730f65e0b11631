"""The paper's Sect. 5.2 experiment on the real SMACS0723 model (Mahler et al. 2023).

A constellation of point sources (Gaussian, sigma = 0.06 arcsec) is placed
at the mean source position of system 4 (z = 2.17, fitted) of the Lenstool
model, its images are solved with the real model, and the estimators are
compared with the model's true magnification ratios of the fold pair.
Needs the model in ../shared/data/smacs0723_mahler2022::

    python benchmarks/real_model_constellation.py [--n-sources 16 30] [--seeds 10]
        [--output docs/_static/lenstool/real_model.txt]

``docs/scripts/lenstool_numbers.py`` turns the stored output into the table
and the numbers of the Lenstool page.
"""

import argparse
import warnings
from pathlib import Path

import astropy.units as u
import numpy as np
from _output import Record, add_output_argument
from astropy.table import vstack

from lensdual.parametric import read_lenstool, read_lenstool_images
from lensdual.simulation.validation import estimator_errors, summarize_errors

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "smacs0723_mahler2022"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-sources", type=int, nargs="+", default=[16, 30])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--sigma", type=float, default=0.06, help="source spread, arcsec")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    record = Record()

    model = read_lenstool(DATA / "best.par")
    images = read_lenstool_images(DATA / "arcs.dat", reference=model)
    sel = images[images["system"] == "4"]
    system = model.lens_system(float(sel["z_model"][0]))
    theta = np.column_stack([sel["x"], sel["y"]])
    centre = system.ray_shoot(theta).to_value(u.arcsec).mean(axis=0)
    record.say(f"system 4 at z = {float(sel['z_model'][0]):.3f}, source centre {centre} arcsec; "
               f"sigma = {args.sigma:g} arcsec")
    for n in args.n_sources:
        rows = []
        for seed in range(args.seeds):
            rng = np.random.default_rng(seed)
            beta = centre + args.sigma * rng.standard_normal((n, 2))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                pairs = system.constellation(beta * u.arcsec)
            errs = estimator_errors(pairs)
            errs["seed"] = seed
            rows.append(errs)
        table = vstack(rows, metadata_conflicts="silent")
        table.meta["methods"] = ["2v", "quad", "quad2"]
        record.say(f"\nN = {n} sources, {args.seeds} constellations, {len(table)} pairs, "
                   f"true ratios {np.min(table['mu_true']):.3f}-{np.max(table['mu_true']):.3f}")
        for r in summarize_errors(table, by=()):
            record.say(f"  {r['method']:6s} median |err| {100 * r['median_abs_err']:6.2f} %   "
                       f"68 % half width {100 * r['half_width_68']:6.2f} %   "
                       f"95 % |err| {100 * r['abs_err_95']:6.2f} %")
    record.write(args.output)


if __name__ == "__main__":
    main()
