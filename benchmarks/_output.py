"""The ``--output FILE`` option of the benchmarks: what they print, also kept in a file.

The docs quote the stored files (``docs/_static/performance/``) through
``docs/scripts/performance_numbers.py``; the first lines of each file say on how
many cores and at what load it was measured.
"""

import os
from pathlib import Path


def add_output_argument(parser):
    """Add ``--output FILE`` to an `argparse.ArgumentParser`."""
    parser.add_argument("--output", type=Path,
                        help="also write what is printed to this file (the docs' record)")


class Record:
    """Print lines and keep them, headed by the cores and the load average."""

    def __init__(self):
        load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
        self.lines = [f"cores: {len(os.sched_getaffinity(0))}",
                      f"load average at start: {load}"]

    def say(self, text=""):
        """Print ``text`` and keep it."""
        print(text, flush=True)
        self.lines.extend(str(text).split("\n"))

    def write(self, path):
        """Write the kept lines to ``path`` (nothing when ``path`` is None)."""
        if path is None:
            return
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(self.lines) + "\n")
