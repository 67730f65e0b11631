"""Write the tables and numbers of docs/validation.rst into docs/_static/validation/.

The tables are those of ``benchmarks/validation_tables.py`` (deterministic,
fixed seeds; about ten seconds per noise level on one core), on exact
positions (``analog.inc``, ``grid.inc``, ``grid_n.inc``) and with 0.01 arcsec
of position noise (``analog_noise.inc``); ``numbers.inc`` holds the numbers
the page's prose quotes from them, and from the noisy grid. Run from the
repository root::

    python docs/scripts/validation_numbers.py
"""

import sys
from pathlib import Path

import astropy.units as u

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import benchmark_module  # noqa: E402
from _substitutions import include_files, value_range, write_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "validation"

#: The position noise of the page's second set of tables.
NOISE = 0.01 * u.arcsec
#: The numbers of sources the prose compares ``quad2`` with ``quad`` at.
MANY = (20, 30)


def _pct(text):
    """The number of a cell such as ``2.50 %``."""
    return float(text.split()[0])


def _column(table, name, **where):
    """The values (in %) of column ``name`` in the rows where the columns of
    ``where`` (names with spaces as underscores) are in the given tuples."""
    header, rows = table
    index = {h.replace(" ", "_"): i for i, h in enumerate(header)}
    return [_pct(r[index[name]]) for r in rows
            if all(r[index[k]] in v for k, v in where.items())]


def _range(values, digits=1):
    return value_range(values, f"{{:.{digits}f}}")


def numbers(exact, noisy):
    """The substitutions read from the tables without and with position noise."""
    med, p95 = "median_abs_err", "95_%_abs_err"
    sub = {"val_quad_median": _range(_column(exact["analog"], med, method=("quad",))),
           "val_quad_tail": _range(_column(exact["analog"], p95, method=("quad",))),
           "val_2v_tail": _range(_column(exact["grid_n"], p95, method=("2v",)))}
    quad = _column(exact["grid_n"], med, method=("quad",), N=MANY)
    quad2 = _column(exact["grid_n"], med, method=("quad2",), N=MANY)
    sub["val_many_quad"] = _range(quad, 2)
    sub["val_many_quad2"] = _range(quad2, 2)
    sub["val_quad2_gain"] = _range([q / q2 for q, q2 in zip(quad, quad2, strict=True)], 0)
    sub["val_noise_bias"] = _range(_column(noisy["analog"], med, method=("quad", "quad2")), 0)
    sub["val_noise_quad"] = _range(_column(noisy["grid_n"], med, method=("quad",), N=MANY), 0)
    sub["val_noise_quad2"] = _range(_column(noisy["grid_n"], med, method=("quad2",), N=MANY),
                                    0)
    return sub


def compute():
    """``({file name: text}, substitutions)``: the tables the page includes and its numbers."""
    module = benchmark_module("validation_tables")
    exact, noisy = module.tables(), module.tables(NOISE)
    files = {f"{name}.inc": module.rst_table(*table) + "\n" for name, table in exact.items()}
    files["analog_noise.inc"] = module.rst_table(*noisy["analog"]) + "\n"
    sub = numbers(exact, noisy)
    return files | include_files(sub), sub


def main(out=OUT):
    """Write the files into ``out`` (the docs' folder by default); returns the substitutions."""
    files, sub = compute()
    write_files(files, out)
    return sub


if __name__ == "__main__":
    main()
