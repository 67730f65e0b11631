"""Wall time of ``lensdual demo``: the first run after install (cold Numba cache) and warm.

Run on demand (a few minutes)::

    python benchmarks/bench_demo_time.py [--runs 2] [--scene realistic]

Each run is a fresh process (``python -m lensdual demo --quiet`` into a
temporary folder) with ``NUMBA_CACHE_DIR`` pointing at a new empty folder for
the first run, so that every kernel compiles as after a fresh install, and at
the same folder for the warm runs. Also reports, from the cold run, where the
compilation goes: the kernels whose compilation (nested kernels included)
took longest, and how long the run waited for the second process that
compiles the duality test's kernels (``lensdual._precompile``). With
``--output FILE`` the figures also go to FILE: the README and the tutorial
quote ``docs/_static/performance/demo_time.txt``, and
``tests/test_docs_numbers.py`` checks that they do. ``--scene realistic``
times ``lensdual demo --scene realistic`` instead (issue 34's target: at most
60 s warm on 2 cores; ``docs/_static/performance/demo_time_realistic.txt``).
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _output import Record, add_output_argument

_PROFILE = r"""
import collections, sys, time
from numba.core import event
import lensdual._precompile as precompile
waited = []
_wait = precompile.wait
def wait():
    t0 = time.perf_counter()
    status = _wait()
    waited.append((time.perf_counter() - t0, status))
    return status
precompile.wait = wait
cm = event.install_recorder("numba:compile")
rec = cm.__enter__()
from lensdual.cli import main
main(["demo", "--outdir", sys.argv[1], "--quiet", *sys.argv[2:]])
cm.__exit__(None, None, None)
for dt, status in waited:
    if status is not None:
        print(f"waited {dt:.1f} s for the second compiling process (exit status {status})")
per, starts = collections.defaultdict(float), {}
for ts, e in rec.buffer:
    d = e.data.get("dispatcher")
    key = f"{d.py_func.__module__}.{d.py_func.__qualname__}" if d is not None else "?"
    if e.is_start:
        starts[(key, id(e.data.get("args")))] = ts
    else:
        t0 = starts.pop((key, id(e.data.get("args"))), None)
        if t0 is not None:
            per[key] += ts - t0
for k, v in sorted(per.items(), key=lambda kv: -kv[1])[:8]:
    print(f"{v:7.1f} s  {k}")
"""


def _run(args, cache, out, extra=()):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *args, str(out), *extra], env=env,
                          capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, proc.stdout


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2, help="warm runs (default 2)")
    parser.add_argument("--scene", default=None, help="the demo's --scene (default its own)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    extra = ("--scene", args.scene) if args.scene else ()
    record = Record()
    if args.scene:
        record.say(f"lensdual demo --scene {args.scene}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cold, profile = _run(["-c", _PROFILE], tmp / "cache", tmp / "cold", extra)
        record.say(f"first run (cold Numba cache): {cold:.1f} s; compilation, nested included:")
        record.say(profile.rstrip())
        warm = []
        for k in range(args.runs):
            warm.append(_run(["-m", "lensdual", "demo", "--quiet", "--outdir"], tmp / "cache",
                             tmp / f"warm{k}", extra)[0])
            record.say(f"warm run {k + 1}: {warm[-1]:.1f} s")
    record.say(f"summary: first {cold:.0f} s, warm {min(warm):.0f}-{max(warm):.0f} s")
    record.write(args.output)

if __name__ == "__main__":
    main()
