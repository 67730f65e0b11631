"""The numbers the docs pages quote are the ones their scripts write now.

Every docs page that quotes a script's numbers includes them from a file the
script wrote (``docs/_static/<topic>/``). Where the script is cheap enough,
this module reruns it and compares with the committed files: a change of the
code that moves a number fails here until the script is rerun and the page
read again.
"""

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "docs" / "scripts"
STATIC = ROOT / "docs" / "_static"


def load_script(name):
    """The module of ``docs/scripts/<name>.py`` (its ``main`` is not run)."""
    spec = importlib.util.spec_from_file_location(f"docs_script_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_files_match(written, folder, script):
    for name, text in written.items():
        committed = (folder / name).read_text()
        assert committed == text, (
            f"{folder.relative_to(ROOT) / name} is not what {script} writes now: rerun it "
            f"and check the page that includes it")


@pytest.fixture(scope="module")
def macs1149_knots():
    hff = os.environ.get("LENSDUAL_HFF_DIR")
    if not hff or not (Path(hff) / "macs1149_v4").is_dir():
        pytest.skip("needs the CATS v4 MACS J1149 model (LENSDUAL_HFF_DIR)")
    module = load_script("macs1149_knots")
    return module, module.compute(Path(hff) / "macs1149_v4")


def test_knots_page_numbers_are_the_scripts(macs1149_knots):
    module, result = macs1149_knots
    assert_files_match(module.include_files(result), STATIC / "knots",
                       "docs/scripts/macs1149_knots.py")


def test_knots_page_includes_the_numbers():
    """Every substitution the page uses is defined by the script's file, and the
    page includes its files (no hand-typed copy of the table)."""
    page = (ROOT / "docs" / "knots.rst").read_text()
    defined = (STATIC / "knots" / "numbers.inc").read_text()
    for name in ("numbers.inc", "table.inc", "summary.txt", "comparison.txt"):
        assert f"_static/knots/{name}" in page
    import re

    used = set(re.findall(r"\|(knots_\w+)\|", page))
    assert used
    assert not used - set(re.findall(r"\|(knots_\w+)\|", defined))
