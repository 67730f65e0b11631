"""The numbers the docs pages quote are the ones their scripts write now.

Every docs page that quotes a script's numbers includes them from a file the
script wrote (``docs/_static/<topic>/``). Where the script is cheap enough,
this module reruns it and compares with the committed files: a change of the
code that moves a number fails here until the script is rerun and the page
read again.
"""

import importlib.util
import os
import re
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


def generated_numbers(tmp_path, script, topic, prefix, files=("numbers.inc",), folder=None):
    """Run ``docs/scripts/<script>.py`` into ``tmp_path``; check that it writes
    ``files`` (its include file and any tables), that they are the committed
    ones in ``folder`` (default ``docs/_static/<topic>/``), that
    ``docs/<topic>.rst`` includes the numbers and that every ``|<prefix>_...|``
    the page uses is defined. Returns the substitutions, the folder and the
    page's text."""
    sub = load_script(script).main(tmp_path)
    folder = STATIC / topic if folder is None else folder
    written = {p.name: p.read_text() for p in tmp_path.iterdir()}
    assert set(written) == set(files)
    assert_files_match(written, folder, f"docs/scripts/{script}.py")
    page = (ROOT / "docs" / f"{topic}.rst").read_text()
    assert f".. include:: {folder.relative_to(ROOT / 'docs')}/numbers.inc" in page
    used = substitutions_used(page, prefix)
    assert used
    assert used <= set(sub)
    return sub, folder, page


def substitutions_used(text, prefix):
    """The names ``<prefix>_...`` of the reST substitutions ``text`` uses or defines."""
    return set(re.findall(rf"\|({prefix}_\w+)\|", text))


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
    used = substitutions_used(page, "knots")
    assert used
    assert not used - substitutions_used(defined, "knots")


@pytest.mark.slow
def test_tutorial_listings_are_the_demos(tmp_path):
    """The tutorial's report, run configuration and broken-configuration message
    are what ``lensdual demo`` prints and writes now (one demo run, ~30 s)."""
    module = load_script("tutorial_figures")
    files, _, _ = module.listings(tmp_path)
    assert_files_match(files, STATIC / "tutorial", "docs/scripts/tutorial_figures.py")


@pytest.mark.slow
def test_sensitivity_reference_errors_are_the_codes():
    """The reference errors docs/sensitivity.rst quotes (``reference.inc``) are
    what smacs0723_reference gives now; the map statistics (``numbers.inc``,
    ``settings.txt``) take minutes and are the committed output of
    docs/scripts/sensitivity_maps.py."""
    module = load_script("sensitivity_maps")
    text = module.substitutions(module.reference_numbers(module.reference_errors()))
    assert_files_match({"reference.inc": text}, STATIC / "sensitivity",
                       "docs/scripts/sensitivity_maps.py")


def test_sensitivity_page_includes_the_numbers():
    page = (ROOT / "docs" / "sensitivity.rst").read_text()
    folder = STATIC / "sensitivity"
    for name in ("numbers.inc", "reference.inc", "settings.txt"):
        assert f"_static/sensitivity/{name}" in page
    defined = set()
    for name in ("numbers.inc", "reference.inc"):
        defined |= substitutions_used((folder / name).read_text(), "sens")
    used = substitutions_used(page, "sens")
    assert used
    assert not used - defined


def test_joint_status_numbers_are_read_from_the_tables():
    """The joint-test page's Status quotes what docs/scripts/joint_status.py reads from
    the calibration tables the page includes, and nothing it does not define."""
    module = load_script("joint_status")
    folder = STATIC / "joint"
    sub = module.compute(module.read_table(folder / "calibration_dev.txt"),
                         module.held_out_rows(folder))
    assert_files_match(module.include_files(sub), folder, "docs/scripts/joint_status.py")
    page = (ROOT / "docs" / "joint_test.rst").read_text()
    assert ".. include:: _static/joint/status.inc" in page
    assert substitutions_used(page, "jt") <= set(sub)
    # an independent count of the cells within the false-flag target
    rows = [ln.split() for ln in (folder / "calibration_dev.txt").read_text().splitlines()[1:]]
    head = (folder / "calibration_dev.txt").read_text().split("\n", 1)[0].split()
    ffr = [float(r[head.index("ffr")]) for r in rows]
    assert sub["jt_cells_ok"] == str(sum(f <= 0.005 for f in ffr))


def test_the_demo_times_quoted_are_the_benchmark_s():
    """README, tutorial and ``lensdual --help`` quote the figures that
    ``benchmarks/bench_demo_time.py --output`` stored."""
    from lensdual.cli import build_parser

    text = (STATIC / "performance" / "demo_time.txt").read_text()
    first, low, high = re.search(r"summary: first (\d+) s, warm (\d+)-(\d+) s", text).groups()
    warm = f"{low}-{high} s"
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert f"({warm}; about {first} s the first time" in readme
    tutorial = " ".join((ROOT / "docs" / "tutorial.rst").read_text().split())
    assert f"takes {warm} with a warm Numba cache and about {first} s the first time" in tutorial
    epilog = " ".join(build_parser().epilog.split())
    assert f"takes {warm} on 2 cores (about {first} s the first time)" in epilog


def test_calibration_numbers_are_read_from_the_tables(tmp_path):
    """The calibration page's prose quotes what docs/scripts/calibration_numbers.py
    writes from the stored benchmark tables (regenerated here into a temporary
    folder), and no number the script does not define."""
    sub, folder, page = generated_numbers(tmp_path, "calibration_numbers", "calibration",
                                          "cal")
    # an independent read of the galaxy group's false flags with 8 sources at 1 mas
    lines = (folder / "heldout_new.txt").read_text().splitlines()
    head = lines[0].split()
    row = next(ln.split() for ln in lines[1:]
               if ln.split()[:4] == ["group_fold", "8", "adaptive", "1"])
    assert sub["cal_group8_ffr1"] == f"{100 * float(row[head.index('ffr')]):.1f}"


def test_calibration_tables_are_the_stored_suite_output(tmp_path):
    """The calibration page's tables are the CSV files that
    ``benchmarks/calibration_tables.py --csv`` writes from the stored output of
    ``benchmarks/calibration.py`` (regenerated here into a temporary folder)."""
    spec = importlib.util.spec_from_file_location(
        "calibration_tables", ROOT / "benchmarks" / "calibration_tables.py")
    tables = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tables)
    folder = STATIC / "calibration"
    cells = tables.read(folder / "suite_seed0.txt")
    written = tables.write_csv(cells, tmp_path)
    assert set(written) == {"main.csv", *(f"{f}.csv" for f in tables.UNTUNED)}
    assert_files_match(written, folder / "tables", "benchmarks/calibration_tables.py --csv")
    page = (ROOT / "docs" / "calibration.rst").read_text()
    for name in written:
        assert f":file: _static/calibration/tables/{name}" in page
    # an independent read of one cell: cluster_fold, 20 sources, 5 mas
    row = next(ln.split() for ln in (folder / "suite_seed0.txt").read_text().splitlines()
               if ln.split()[:4] == ["cluster_fold", "20", "adaptive", "5"])
    head = (folder / "suite_seed0.txt").read_text().splitlines()[0].split()
    ffr = 100 * float(row[head.index("ffr")])
    line = next(ln for ln in written["main.csv"].splitlines()
                if ln.startswith("cluster_fold, 20, 5,"))
    assert line.split(", ")[4].startswith(f"{ffr:.2f} / ")


def test_performance_numbers_are_the_benchmarks_outputs(tmp_path):
    """docs/performance.rst quotes what docs/scripts/performance_numbers.py reads from
    the benchmarks' stored outputs (regenerated here into a temporary folder), and
    no number the script does not define."""
    sub, folder, page = generated_numbers(tmp_path, "performance_numbers", "performance",
                                          "perf")
    # every stored output the script reads is named on the page, with its benchmark
    for name in load_script("performance_numbers").READERS:
        assert f"_static/performance/{name}" in page
    # an independent read of the quad estimator's speed-up against the numpy reference
    line = next(ln.split() for ln in (folder / "estimators.txt").read_text().splitlines()
                if ln.split()[:1] == ["quad"])
    assert sub["perf_est_quad_ratio"] == line[-1]
    assert float(line[2]) / float(line[1]) == pytest.approx(float(line[-1][:-1]), abs=1)


def test_pairing_numbers_are_the_benchmarks_outputs(tmp_path):
    """docs/pairing.rst's tables and numbers are what docs/scripts/pairing_numbers.py
    writes from the stored outputs of benchmarks/pairing_accuracy.py and
    bench_scale_pairing.py (regenerated here into a temporary folder)."""
    files = ("numbers.inc", "accuracy.csv", "smacs.csv")
    sub, folder, page = generated_numbers(tmp_path, "pairing_numbers", "pairing", "pair", files)
    for name in files[1:]:
        assert f":file: _static/pairing/{name}" in page
    # an independent count of the systems and refusals over the first table's rows
    # (columns from the right: ms/system, quadratic, refused, ...; "15 + 15" points)
    lines = (folder / "accuracy.txt").read_text().splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("case ")) + 1
    end = next(i for i, ln in enumerate(lines) if ln.startswith(("refused:", "SMACS")))
    rows = [ln.split() for ln in lines[start:end]]
    assert len(rows) == 11
    assert sub["pair_refused_total"] == str(sum(int(r[-3]) for r in rows))
    assert sub["pair_systems_total"] == str(sum(int(r[-10]) for r in rows))


def test_detection_numbers_are_the_benchmark_s(tmp_path):
    """docs/detection.rst's timings are what docs/scripts/detection_numbers.py reads
    from the stored output of benchmarks/bench_detection.py."""
    sub, folder, page = generated_numbers(tmp_path, "detection_numbers", "detection", "det")
    assert "_static/detection/timings.txt" in page
    # the ratio quoted is the quoted filter time over the quoted blur time
    ratio = float(sub["det_filter_time"]) / float(sub["det_blurs_time"])
    assert float(sub["det_filter_ratio"]) == pytest.approx(ratio, abs=0.02)


def test_inference_numbers_are_the_benchmarks_outputs(tmp_path):
    """docs/inference.rst quotes what docs/scripts/inference_numbers.py reads from the
    stored coverage, WDM and posterior runs it includes, and its prose's claims
    about them hold."""
    sub, folder, page = generated_numbers(tmp_path, "inference_numbers", "inference", "inf")
    module = load_script("inference_numbers")
    for name in ("coverage.txt", "coverage_heldout.txt", "coverage_heldout_cusp.txt",
                 "coverage_oracle.txt", "wdm.txt", "posterior.txt"):
        assert f"_static/inference/{name}" in page
    _, dev = module.read_coverage(folder / "coverage.txt")
    _, held = module.read_coverage(folder / "coverage_heldout.txt")
    # "with oracle noise the coverage came back to nominal" (weight 1)
    _, oracle = module.read_coverage(folder / "coverage_oracle.txt")
    row = oracle["smacs_analog"]["rows"][0]
    for key, target in (("cov68", module.TARGET68), ("cov95", module.TARGET95)):
        assert abs(row[key] - target[0]) <= target[1]
    # "On Abell 2744 the weight comes out 1, so no correction is applied, and the
    # intervals there are too narrow: the 95 % intervals ... miss their target"
    a2744 = module.weighted(held[module.HELD_OUT])
    assert float(a2744["w"]) == 1.0
    assert a2744["cov95"] < module.TARGET95[0] - module.TARGET95[1]
    # "the posterior median sits above a truth near the lower prior bound and below
    # a truth in the middle"; "the target of 0.1 dex is met by the median over the prior"
    for family in module.DEVELOPMENT:
        row = module.weighted(dev[family])
        assert row["bins"][module.LOW_BIN]["bias_median"] > 0
        assert row["bins"][module.MID_BIN]["bias_median"] < 0
        assert abs(row["bias_median"]) <= module.MAX_BIAS
    # "the numbers are not monotonic in the astrometry"
    runs, _ = module.read_wdm(folder / "wdm.txt")
    n95 = [float(runs[mas][1]) for mas in sorted(runs, key=float)]
    assert n95 != sorted(n95) and n95 != sorted(n95, reverse=True)


def _included_numbers(page):
    """The substitutions defined by the ``.inc`` files a docs page includes."""
    defined = set()
    for name in re.findall(r"^\.\. include:: (_static/\S+\.inc)$", page, re.MULTILINE):
        defined |= set(re.findall(r"^\.\. \|(\w+)\| replace::",
                                  (ROOT / "docs" / name).read_text(), re.MULTILINE))
    return defined


def test_every_generated_number_a_page_uses_is_included():
    """A page that uses a generated number (a substitution whose prefix one of the
    scripts' include files defines) includes the file that defines it."""
    prefixes = set()
    for inc in STATIC.rglob("*.inc"):
        prefixes |= {name.split("_", 1)[0] for name in
                     re.findall(r"^\.\. \|(\w+?_\w+)\| replace::", inc.read_text(),
                                re.MULTILINE)}
    assert {"cal", "perf", "pair", "det", "inf"} <= prefixes
    for path in sorted((ROOT / "docs").glob("*.rst")):
        page = path.read_text()
        used = {name for name in re.findall(r"\|(\w+?_\w+)\|", page)
                if name.split("_", 1)[0] in prefixes}
        missing = used - _included_numbers(page)
        assert not missing, f"docs/{path.name} uses {sorted(missing)} without including them"


@pytest.mark.slow
def test_validation_tables_are_the_codes(tmp_path):
    """docs/validation.rst's tables and the numbers its prose quotes are what
    docs/scripts/validation_numbers.py computes now (benchmarks/validation_tables.py
    without and with position noise, deterministic; ~15 s)."""
    files = ("numbers.inc", "analog.inc", "grid.inc", "grid_n.inc", "analog_noise.inc")
    sub, folder, page = generated_numbers(tmp_path, "validation_numbers", "validation", "val",
                                          files)
    for name in files[1:]:
        assert f".. include:: _static/validation/{name}" in page
    # an independent read: the Quad estimator's median errors on the analogue
    analog = (folder / "analog.inc").read_text().splitlines()
    quad = [float(ln.split()[-6]) for ln in analog if " quad " in ln]
    assert sub["val_quad_median"] == f"{min(quad):.1f}-{max(quad):.1f}"


def test_lenstool_real_model_numbers_are_the_benchmark_s(tmp_path):
    """The Lenstool page's table of the experiment on the real SMACS0723 model is
    what docs/scripts/lenstool_numbers.py writes from the stored output of
    benchmarks/real_model_constellation.py."""
    files = ("numbers.inc", "real_model.csv")
    sub, folder, page = generated_numbers(tmp_path, "lenstool_numbers", "lenstool", "lt",
                                          files)
    assert ":file: _static/lenstool/real_model.csv" in page


def test_lenstool_real_model_output_is_the_code_s(tmp_path, monkeypatch):
    """The stored output of benchmarks/real_model_constellation.py is what it gives
    now (3 s; needs the SMACS0723 Lenstool model)."""
    data = ROOT.parent / "shared" / "data" / "smacs0723_mahler2022"
    if not (data / "best.par").is_file():
        pytest.skip("needs the SMACS0723 Lenstool model (../shared/data)")
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    out = tmp_path / "real_model.txt"
    spec = importlib.util.spec_from_file_location(
        "real_model_constellation", ROOT / "benchmarks" / "real_model_constellation.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(["--output", str(out)])
    # the first two lines are the cores and the load average
    stored = (STATIC / "lenstool" / "real_model.txt").read_text().splitlines()[2:]
    assert out.read_text().splitlines()[2:] == stored


def test_parametric_cases_are_the_benchmark_s(tmp_path):
    """The parametric-fits page's tables and numbers are what
    docs/scripts/parametric_numbers.py writes from the stored output of
    benchmarks/parametric_cases.py, and its prose's claims about them hold."""
    files = ("numbers.inc", "cases_006.csv", "cases_001.csv")
    sub, folder, page = generated_numbers(tmp_path, "parametric_numbers", "parametric_fits",
                                          "par", files, folder=STATIC / "parametric")
    for name in files[1:]:
        assert f":file: _static/parametric/{name}" in page
    runs = load_script("parametric_numbers").read(folder / "cases.txt")
    coarse, fine = runs["0.06"], runs["0.01"]
    # (b): "e1 and gamma1 at their bounds" (+-0.5), "the drift is not flagged"
    best = coarse["b"]["best"]
    assert abs(best["e1"]) > 0.499 and abs(best["gamma1"]) > 0.499
    assert coarse["b"]["flag_model"] == fine["b"]["flag_model"] == "none"
    assert float(fine["b"]["chi2"]) < int(fine["b"]["dof"])
    # (c): pair 1 is the worst of both, and neither flags it at 0.06 arcsec
    assert coarse["c"]["worst_size"] == coarse["c"]["worst_model"] == 1
    assert coarse["c"]["flag_size"] == coarse["c"]["flag_model"] == "none"
    # "the best fits and all the ratios are the same as at 0.06 arcsec" (case (a)'s
    # parametric ratios are exact, to rounding)
    for case in "abc":
        assert coarse[case]["best"]["Rs"] == fine[case]["best"]["Rs"]
        for field in ("size_med", "size_max") + (("model_max",) if case != "a" else ()):
            assert coarse[case][field] == fine[case][field]
    # "the parametric errors do not shrink" as mu_size's do
    for case in "ab":
        size = float(coarse[case]["relerr_size"]) / float(fine[case]["relerr_size"])
        model = float(coarse[case]["relerr_model"]) / float(fine[case]["relerr_model"])
        assert model < size / 2


def test_inference_page_host_scaling_is_pyhalo_s():
    """docs/inference.rst: "With it (log_m_host=15), F = 12 at z = 0.39"."""
    pytest.importorskip("pyHalo")
    from lensdual.inference import SubhaloPopulation

    pop = SubhaloPopulation(z_lens=0.39, z_source=2.2, log_m_host=15)
    page = " ".join((ROOT / "docs" / "inference.rst").read_text().split())
    assert f":math:`F = {round(pop._host_scaling)}` at :math:`z = 0.39`" in page


def test_resolved_photometry_numbers_are_read_from_the_record():
    """The resolved-fit numbers of docs/mock_images.rst and docs/photometry.rst are what
    docs/scripts/resolved_numbers.py reads from the benchmark's stored output, which
    the page includes whole."""
    module = load_script("resolved_numbers")
    folder = STATIC / "scenes"
    stamps, anomaly, demo = module.read_record(folder / module.RECORD)
    sub = module.compute(stamps, anomaly, demo)
    assert_files_match(module.include_files(sub), folder,
                       "docs/scripts/resolved_numbers.py")
    for name in ("mock_images", "photometry"):
        page = (ROOT / "docs" / f"{name}.rst").read_text()
        assert ".. include:: _static/scenes/resolved.inc" in page
        assert substitutions_used(page, "rs") <= set(sub)
    page = (ROOT / "docs" / "mock_images.rst").read_text()
    assert "literalinclude:: _static/scenes/resolved_photometry.txt" in page
    # an independent read of the largest resolved bias: the 5th number of each stamp row
    text = (folder / module.RECORD).read_text().split("2. The demo")[0]
    rows = [ln.replace("|", " ").split() for ln in text.splitlines()
            if ln.count("|") == 3 and ln.strip()[:1].isdigit()]
    assert len(rows) == len(stamps) > 0
    worst = max(abs(float(r[6])) for r in rows)
    assert sub["rs_resolved_maxbias"] == f"{100 * worst:.1f} %"
