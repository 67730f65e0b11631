"""The include file of a docs page's numbers: one reST substitution per number."""

from pathlib import Path


def include_files(sub):
    """``{"numbers.inc": text}``: one reST substitution per number of ``sub``."""
    text = "".join(f".. |{k}| replace:: {v}\n" for k, v in sub.items())
    return {"numbers.inc": text}


def write(sub, out):
    """Write the include file of ``sub`` into the folder ``out`` (and print it)."""
    for name, text in include_files(sub).items():
        (Path(out) / name).write_text(text)
        print(text, end="")
    return sub
