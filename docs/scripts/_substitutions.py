"""The files a docs page includes: its numbers, one reST substitution per number,
and its CSV tables; and the text of the numbers' ranges."""

import csv
import io
from pathlib import Path


def include_files(sub):
    """``{"numbers.inc": text}``: one reST substitution per number of ``sub``."""
    text = "".join(f".. |{k}| replace:: {v}\n" for k, v in sub.items())
    return {"numbers.inc": text}


def write_files(files, out):
    """Write ``{file name: text}`` into the folder ``out`` (made if need be) and
    print the include file ``numbers.inc``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (out / name).write_text(text)
    print(files["numbers.inc"], end="")


def write(sub, out):
    """Write the include file of ``sub`` into the folder ``out`` (and print it)."""
    write_files(include_files(sub), out)
    return sub


def csv_text(rows):
    """CSV text in the dialect of the ``csv-table`` directive."""
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def value_range(values, fmt="{:.1f}", unit=""):
    """``lo-hi`` of ``values``, each formatted with ``fmt``; one number when both read
    the same."""
    lo, hi = fmt.format(min(values)), fmt.format(max(values))
    return f"{lo}{unit}" if lo == hi else f"{lo}-{hi}{unit}"
