"""Readers of the benchmarks' stored outputs (``benchmarks/_output.py``'s Record
files), shared by the docs' scripts."""

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def read_lines(path):
    """The lines of a stored output."""
    return Path(path).read_text().splitlines()


def search(pattern, lines, path):
    """The match of ``pattern`` in the first line it matches."""
    for line in lines:
        m = re.search(pattern, line)
        if m:
            return m
    raise ValueError(f"{path}: no line matches {pattern!r}")


def header(path):
    """The cores and the load average at the start of a stored output (text)."""
    lines = read_lines(path)
    cores = search(r"^cores: (\d+)", lines, path).group(1)
    load = search(r"^load average at start: ([\d.]+)", lines, path).group(1)
    return cores, load


def benchmark_module(name):
    """The module of ``benchmarks/<name>.py`` (its ``main`` is not run)."""
    path = ROOT / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
