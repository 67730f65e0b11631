"""Make the tutorial's figures and listings from a real run of ``lensdual demo``.

Runs ``lensdual demo --write-config`` and ``lensdual run`` on the written
configuration in a temporary directory and copies into ``docs/_static/tutorial/``:
the printed report, the two figures, the configuration file and the message
of a deliberately broken configuration. Run it from the repository root
after changing the pipeline::

    python docs/scripts/tutorial_figures.py
"""

import contextlib
import io
import shutil
import tempfile
import time
from pathlib import Path

from lensdual.cli import main

HERE = Path(__file__).resolve().parent
STATIC = HERE.parent / "_static" / "tutorial"


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    start = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue(), time.perf_counter() - start


def listings(tmp):
    """Run ``lensdual demo --write-config`` into ``tmp`` and make the listings.

    Returns ``({file name: text}, demo folder, seconds the demo took)``: the
    printed report, the configuration file and the message of a deliberately
    broken configuration (``tests/test_docs_numbers.py`` compares them with the
    committed files).
    """
    tmp = Path(tmp)
    code, out, _, secs = run(["demo", "--outdir", str(tmp / "lensdual-demo"), "--write-config"])
    assert code == 0
    demo = tmp / "lensdual-demo"
    text = out.rsplit("\nOutputs in", 1)[0]
    files = {"demo_output.txt": "$ lensdual demo --write-config\n" + text
             + "\n\nOutputs in lensdual-demo.\n",
             "run.toml": (demo / "run.toml").read_text()}
    broken = files["run.toml"].replace('estimator = "adaptive"', 'estimator = "adaptiv"')
    broken = broken.replace('sigma_pos = "auto"', 'sigma_pos = "0.01"')
    broken = broken.replace("data/L2_F200W_err.fits", "data/L2_F200W_error.fits")
    (demo / "broken.toml").write_text(broken)
    code, _, err, _ = run(["run", str(demo / "broken.toml")])
    assert code == 2
    err = err.replace(str(demo), "lensdual-demo")
    files["broken_config.txt"] = ("$ lensdual run lensdual-demo/broken.toml\n" + err
                                  + f"$ echo $?\n{code}\n")
    return files, demo, secs


def main_script():
    STATIC.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        files, demo, secs = listings(tmp)
        for name, text in files.items():
            (STATIC / name).write_text(text)
        for name in ("duality.png", "pairing_map.png"):
            shutil.copy(demo / name, STATIC / name)
        code, out, _, _ = run(["run", str(demo / "run.toml"), "--quiet"])
        assert code == 0
    print(f"demo took {secs:.1f} s; files in {STATIC}")


if __name__ == "__main__":
    main_script()
