"""Print the validation tables of docs/validation.rst (estimator errors vs truth).

Run on demand::

    python benchmarks/validation_tables.py [--noise 0.0]

Deterministic (fixed seeds): the same numbers as the figures the docs build
computes. ``--noise`` adds Gaussian position noise (arcsec) before estimating.
"""

import argparse

import astropy.units as u

from lensdual.simulation.validation import analog_errors, appendix_b_grid, summarize_errors


def rst_table(header, rows):
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=True)]
    line = "  ".join("=" * w for w in widths)
    out = [line, "  ".join(str(h).ljust(w) for h, w in zip(header, widths, strict=True)), line]
    out += ["  ".join(str(x).ljust(w) for x, w in zip(r, widths, strict=True)) for r in rows]
    out.append(line)
    return "\n".join(out)


def pct(x):
    return f"{100 * x:.2f} %"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", type=float, default=0.0, help="position noise, arcsec")
    args = parser.parse_args(argv)
    noise = args.noise * u.arcsec

    rows = []
    for perturbers in (False, True):
        table = analog_errors(perturbers=perturbers, seeds=range(10), position_noise=noise)
        for r in summarize_errors(table, by=()):
            rows.append(("with members" if perturbers else "main halo only", r["method"],
                         r["n"], pct(r["median_abs_err"]), pct(r["half_width_68"]),
                         pct(r["abs_err_95"])))
    print(rst_table(("case", "method", "pairs", "median abs err", "68 % half width",
                     "95 % abs err"), rows))
    print()

    grid = appendix_b_grid(seed=0, position_noise=noise)
    summary = summarize_errors(grid)
    methods = grid.meta["methods"]
    rows = []
    for key in sorted({(r["target_ratio"], r["n_sources"]) for r in summary}, reverse=True):
        sel = [r for r in summary if (r["target_ratio"], r["n_sources"]) == key]
        rows.append((f"{key[0]:g}", key[1]) + tuple(
            f"{pct(r['median_abs_err'])} / {pct(r['abs_err_95'])}"
            for m in methods for r in sel if r["method"] == m))
    print(rst_table(("ratio", "N") + tuple(methods), rows))
    print()
    rows = []
    for r in summarize_errors(grid, by=("n_sources",)):
        rows.append((r["n_sources"], r["method"], pct(r["median_abs_err"]),
                     pct(r["half_width_68"]), pct(r["abs_err_95"]), pct(r["max_abs_err"])))
    print(rst_table(("N", "method", "median abs err", "68 % half width", "95 % abs err",
                     "max abs err"), rows))


if __name__ == "__main__":
    main()
