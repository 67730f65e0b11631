"""CPU time to compile the Numba kernels: a fresh interpreter on one core, empty cache.

Run on demand (about a minute)::

    python benchmarks/bench_compile.py [--output FILE]

Each case runs in a fresh Python process pinned to one core, first with
``NUMBA_CACHE_DIR`` pointing at a new empty folder (every kernel it uses
compiles, as after a fresh install) and then at the same folder again (the
kernels load from the cache); the compilation is the difference. The times are
the child's CPU time (user plus system), which a busy machine changes less than
the wall time (also printed). The cases:

* ``adaptive``: ``lensdual._precompile.compile_kernels()``, what the second
  process of ``lensdual demo`` and ``lensdual run`` compiles (the adaptive
  duality test and a null calibration on a small constellation);
* ``lenstool``: the dPIE kernels of the SMACS0723 Lenstool model (``alpha``,
  ``hessian`` and ``alpha_hessian`` on a few points) and the elliptical NFW
  kernel (skipped without the model in ``LENSDUAL_SMACS0723_DIR`` or
  ``../shared/data``).

With ``--output FILE`` the figures also go to FILE: ``docs/install.rst`` and
``docs/lenstool.rst`` quote ``docs/_static/performance/compile.txt`` through
``docs/scripts/performance_numbers.py``.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _output import Record, add_output_argument

HERE = Path(__file__).resolve().parent
DATA = Path(os.environ.get("LENSDUAL_SMACS0723_DIR",
                           HERE.parents[1] / "shared" / "data" / "smacs0723_mahler2022"))

#: The code each case runs in a fresh interpreter.
CASES = {
    "adaptive": """
from lensdual._precompile import compile_kernels
compile_kernels()
""",
    "lenstool": f"""
import numpy as np
from lensdual.parametric import LenstoolLensModel, read_lenstool
x, y = np.linspace(-30.0, 30.0, 10), np.linspace(-20.0, 25.0, 10)
lens = read_lenstool({str(DATA / "best.par")!r}).lens_model(2.0)
lens.alpha_hessian(x, y)
lens.alpha(x, y)
lens.hessian(x, y)
LenstoolLensModel(nfw=[[0.0, 0.0, 0.3, 0.2, 30.0, 20.0]]).alpha_hessian(x, y)
""",
}


def _one_core():
    """Pin the child process to the first core this process may use."""
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_case(code, cache):
    """CPU and wall time (s) of ``code`` in a fresh interpreter on one core, with the
    Numba cache ``cache``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS="1",
               LENSDUAL_PRECOMPILE="0")
    cpu, start = _children_cpu(), time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True, preexec_fn=_one_core)
    return _children_cpu() - cpu, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    rec.say("fresh interpreter on one core: empty Numba cache, then the same cache warm; "
            "CPU time (wall time)")
    rec.say(f"{'case':<10}{'cold [s]':>16}{'warm [s]':>16}{'compile [s]':>13}")
    for name, code in CASES.items():
        if name == "lenstool" and not (DATA / "best.par").is_file():
            rec.say(f"{name:<10}skipped: no SMACS0723 model in {DATA}")
            continue
        with tempfile.TemporaryDirectory() as tmp:
            cold, cold_wall = run_case(code, Path(tmp))
            warm, warm_wall = run_case(code, Path(tmp))
        rec.say(f"{name:<10}{cold:>8.1f} ({cold_wall:>5.1f}){warm:>8.1f} ({warm_wall:>5.1f})"
                f"{cold - warm:>13.1f}")
    rec.write(args.output)


if __name__ == "__main__":
    main()
