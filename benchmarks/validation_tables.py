"""Print the validation tables of docs/validation.rst (estimator errors vs truth).

Run on demand::

    python benchmarks/validation_tables.py [--noise 0.0]

Deterministic (fixed seeds): the same numbers as the figures the docs build
computes. ``--noise`` adds Gaussian position noise (arcsec) before estimating.
``docs/scripts/validation_numbers.py`` writes the tables the page includes and
the numbers it quotes from them (with and without noise).
"""

import argparse

import astropy.units as u

from lensdual.simulation.validation import analog_errors, appendix_b_grid, summarize_errors


def rst_table(header, rows):
    """A reST simple table of ``rows`` under ``header``."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=True)]
    line = "  ".join("=" * w for w in widths)
    out = [line, "  ".join(str(h).ljust(w) for h, w in zip(header, widths, strict=True)), line]
    out += ["  ".join(str(x).ljust(w) for x, w in zip(r, widths, strict=True)) for r in rows]
    out.append(line)
    return "\n".join(row.rstrip() for row in out)


def pct(x):
    return f"{100 * x:.2f} %"


def tables(noise=0.0 * u.arcsec):
    """The three tables: ``{"analog": ..., "grid": ..., "grid_n": ...}``, each a
    ``(header, rows)`` of the SMACS0723 analogue's errors, the App. B grid's
    errors per panel and the grid's errors per number of sources."""
    rows = []
    for perturbers in (False, True):
        table = analog_errors(perturbers=perturbers, seeds=range(10), position_noise=noise)
        for r in summarize_errors(table, by=()):
            rows.append(("with members" if perturbers else "main halo only", r["method"],
                         r["n"], pct(r["median_abs_err"]), pct(r["half_width_68"]),
                         pct(r["abs_err_95"])))
    out = {"analog": (("case", "method", "pairs", "median abs err", "68 % half width",
                       "95 % abs err"), rows)}

    grid = appendix_b_grid(seed=0, position_noise=noise)
    summary = summarize_errors(grid)
    methods = grid.meta["methods"]
    rows = []
    for key in sorted({(r["target_ratio"], r["n_sources"]) for r in summary}, reverse=True):
        sel = [r for r in summary if (r["target_ratio"], r["n_sources"]) == key]
        rows.append((f"{key[0]:g}", key[1]) + tuple(
            f"{pct(r['median_abs_err'])} / {pct(r['abs_err_95'])}"
            for m in methods for r in sel if r["method"] == m))
    out["grid"] = (("ratio", "N") + tuple(methods), rows)
    rows = []
    for r in summarize_errors(grid, by=("n_sources",)):
        rows.append((r["n_sources"], r["method"], pct(r["median_abs_err"]),
                     pct(r["half_width_68"]), pct(r["abs_err_95"]), pct(r["max_abs_err"])))
    out["grid_n"] = (("N", "method", "median abs err", "68 % half width", "95 % abs err",
                      "max abs err"), rows)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", type=float, default=0.0, help="position noise, arcsec")
    args = parser.parse_args(argv)
    print("\n\n".join(rst_table(*table) for table in tables(args.noise * u.arcsec).values()))


if __name__ == "__main__":
    main()
