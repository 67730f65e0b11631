"""Writing a nested dictionary as TOML text (:func:`format_config`) or as a file,
atomically (:func:`write_config`); the TOML spelling of keys and table names."""

import math
import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
_ESCAPES = {"\b": r"\b", "\t": r"\t", "\n": r"\n", "\f": r"\f", "\r": r"\r", '"': r"\"",
            "\\": r"\\"}


def _toml_string(text):
    """``text`` as a TOML basic string."""
    out = []
    for ch in text:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(key):
    """``key`` as a TOML key: bare when it can be, else quoted."""
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _sec(*parts):
    """The TOML name of a table, e.g. ``arcs.L1.F150W``."""
    return ".".join(_toml_key(str(p)) for p in parts)



def _toml_value(value, where):
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v, f"{where}[{i}]") for i, v in enumerate(value)) + "]"
    raise TypeError(f"format_config: {where} is a {type(value).__name__}, which cannot be "
                    "written (use str, int, float, bool, lists of those, or dicts)")


def _emit_table(table, path, lines):
    for key in table:
        if not isinstance(key, str):
            where = f" in [{_sec(*path)}]" if path else ""
            raise TypeError(f"format_config: the keys must be strings, got {key!r}{where}")
    values = [(k, v) for k, v in table.items() if not isinstance(v, Mapping)]
    tables = [(k, v) for k, v in table.items() if isinstance(v, Mapping)]
    if path and (values or not tables):
        if lines:
            lines.append("")
        lines.append(f"[{_sec(*path)}]")
    for key, value in values:
        where = ".".join((*path, key))
        lines.append(f"{_toml_key(key)} = {_toml_value(value, where)}")
    for key, sub in tables:
        _emit_table(sub, (*path, key), lines)


def format_config(data, header=None):
    """Write a nested dictionary as TOML text.

    Parameters
    ----------
    data : dict
        String keys; values are str, int, float, bool, lists (or tuples) of
        those, or nested dicts, which become tables (``[a.b.c]``). Keys that
        are not bare TOML keys are quoted.
    header : str, optional
        A comment block to put first (each line prefixed with ``#``).

    Returns
    -------
    str
        The TOML text; ``tomllib.loads(format_config(d)) == d`` for such a
        ``d`` without tuples or NaN.

    Raises
    ------
    TypeError
        A key is not a string or a value has another type.
    """
    if not isinstance(data, Mapping):
        raise TypeError(f"format_config: data must be a dict, got {type(data).__name__}")
    lines = []
    _emit_table(data, (), lines)
    head = []
    if header:
        head = [f"# {line}".rstrip() for line in header.splitlines()]
        if lines:
            head.append("")
    return "\n".join(head + lines) + "\n"


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_config(path, data, header=None):
    """Write a nested dictionary as a TOML file, atomically.

    The text of :func:`format_config` is written to a temporary file in the
    same directory, which then replaces ``path`` (`os.replace`): readers
    never see a partly written file.

    Parameters
    ----------
    path : path-like
        The file to write (replaced if it exists).
    data : dict
        See :func:`format_config`.
    header : str, optional
        A leading comment block.

    Returns
    -------
    `~pathlib.Path`
        ``path``.
    """
    path = Path(path)
    text = format_config(data, header=header)
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
