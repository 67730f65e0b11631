"""The ``lensdual`` command: demo, run on the demo's config, bad configs."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from _demo_config import absolute_config as _absolute_config
from _demo_config import run_demo
from _demo_config import write as _write
from _lenstool_text import COSMOLOGY
from astropy.table import QTable

from lensdual.cli import main

FAST = ["--n-sources", "8", "--n-bootstrap", "200", "--seed", "3"]

DOCUMENTED_COLUMNS = [
    "pair_id", "id1", "id2", "x1", "y1", "x2", "y2", "sky1", "sky2", "pos_err1", "pos_err2",
    "flux1_F150W", "flux2_F150W", "flux_err1_F150W", "flux_err2_F150W",
    "flux1_F200W", "flux2_F200W", "flux_err1_F200W", "flux_err2_F200W",
    "jacobian", "parity", "mu_size", "mu_size_err", "mu_size_p16", "mu_size_p84",
    "mu_flux_F150W", "mu_flux_err_F150W", "mu_flux_F200W", "mu_flux_err_F200W",
    "mu_flux", "mu_flux_err", "duality_ratio", "duality_ratio_err", "snr", "snr_paper",
    "anomalous", "ln_mu_size_err", "mu_size_status", "tested", "p_value", "p_value_holm",
    "p_value_empirical",
]
OUTPUTS = ["pairs.ecsv", "catalog_L1.ecsv", "catalog_L2.ecsv", "pairing_map.png",
           "duality.png", "report.txt"]


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    """One small demo run (8 sources, 200 bootstraps) with its run config."""
    return run_demo(tmp_path_factory, "cli", FAST)


def test_demo_writes_everything(demo_dir):
    for name in OUTPUTS + ["truth_comparison.ecsv", "run.toml"]:
        assert (demo_dir / name).is_file(), name
    for arc in ("L1", "L2"):
        for band in ("F150W", "F200W"):
            assert (demo_dir / "images" / f"{arc}_{band}.fits").is_file()
            assert (demo_dir / "data" / f"{arc}_{band}_sci.fits").is_file()
            assert (demo_dir / "data" / f"{arc}_{band}_err.fits").is_file()
    # no temporary directory left behind
    assert not [p for p in demo_dir.parent.iterdir() if ".partial-" in p.name]


def test_demo_table_columns_and_verdict(demo_dir):
    table = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    missing = [c for c in DOCUMENTED_COLUMNS if c not in table.colnames]
    assert not missing
    assert len(table) == 8
    assert table["jacobian"].shape == (8, 2, 2)
    meta = table.meta["duality"]
    assert meta["method"] == "adaptive"
    assert meta["n_tested"] == int(np.sum(table["tested"]))
    np.testing.assert_allclose(meta["expected_false_flags"], meta["n_tested"] * 0.0026998,
                               rtol=1e-4)
    null = meta["null_calibration"]
    assert null["n_realisations"] == 1000 and 0 <= null["false_alarm_rate"] < 0.05
    report = (demo_dir / "report.txt").read_text()
    assert f"1 pair of {meta['n_tested']} tested flagged" in report
    assert "simulated clean constellations like this one" in report
    truth = QTable.read(demo_dir / "truth_comparison.ecsv", format="ascii.ecsv")
    assert truth.meta["n_matched"] == 8
    # the sub-haloed pair is flagged, and no other
    flagged = np.asarray(table["anomalous"], dtype=bool)
    sub = np.asarray(truth["subhalo"], dtype=bool)
    assert sub.sum() == 1
    assert np.array_equal(flagged, sub)
    assert truth.meta["subhalo_flagged"] is True
    assert truth.meta["false_flags"] == 0
    # the size magnification of the clean pairs against the true smooth-lens ratio
    assert np.nanmedian(np.abs(truth["size_error"])) < 0.05
    # the flux ratio of the sub-haloed pair follows the perturbed truth, not the macro one
    row = truth[sub][0]
    assert abs(row["flux_error"]) < 0.1
    assert row["mu_true"] / row["mu_macro"] < 0.8


def test_the_demo_does_not_distrust_its_null_calibration(demo_dir):
    """The demo's report, with its null calibration, carries no caveat that the null
    map does not follow the pairs (it read "the null map (a degree-2 polynomial) fits
    the pairs with chi2/dof = 4.5: ... may be optimistic"); nor does the flagship
    demo's report that the tutorial quotes (compared with a fresh demo by
    tests/test_docs_numbers.py)."""
    table = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    assert table.meta["duality"]["null_calibration"]["map_interpolates"] is False
    tutorial = Path(__file__).parents[1] / "docs" / "_static" / "tutorial" / "demo_output.txt"
    for report in ((demo_dir / "report.txt").read_text(), tutorial.read_text()):
        assert "simulated clean constellations like this one (null calibration)" in report
        for caveat in ("null map", "interpolates the pairs", "optimistic", "chi2/dof"):
            assert caveat not in report


def test_demo_prints_table_and_truth(tmp_path, capsys):
    out = tmp_path / "loud"
    assert main(["demo", "--outdir", str(out), "--subhalo", "none", *FAST]) == 0
    printed = capsys.readouterr().out
    assert "mu_size" in printed and "SNR" in printed
    assert "No pair breaks geometrical duality" in printed
    assert "No sub-halo was injected. False flags: 0." in printed
    assert printed.count("\n   ") >= 8  # one line per pair
    report = (out / "report.txt").read_text()
    assert "No pair breaks geometrical duality" in report


def test_quiet_prints_nothing(tmp_path, capsys):
    assert main(["demo", "--outdir", str(tmp_path / "q"), "--quiet", "--n-sources", "5",
                 "--n-bootstrap", "20", "--estimator", "quad2"]) == 0
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == ""
    # the default test is the geometric one with quad2, and the report says why
    assert ("Geometric test: the joint test needs the adaptive estimator, not quad2."
            in (tmp_path / "q" / "report.txt").read_text())


@pytest.mark.parametrize("command", ["demo", "run"])
def test_help_explains_every_option(command, capsys):
    assert main([command, "--help"]) == 0
    text = capsys.readouterr().out
    options = {"demo": ["--outdir", "--subhalo", "--seed", "--n-sources", "--n-bootstrap",
                        "--estimator", "--snr-threshold", "--write-config", "--parametric",
                        "--scene", "--cluster-radii", "--quiet"],
               "run": ["config", "--outdir", "--quiet"]}[command]
    for option in options:
        assert option in text
    assert "pairs.ecsv" in text
    if command == "run":  # the whole configuration schema
        for key in ("[analysis]", "sigma_pos", "[bands.F150W]", "psf_fwhm", "[arcs.L1.F150W]",
                    "weight", "[catalogs]", "[pairing]", "[parametric]", "z_source"):
            assert key in text, key


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["demo", "--subhalo", "huge", "--outdir", str(tmp_path / "x")]) == 2
    assert "invalid choice" in capsys.readouterr().err
    assert main(["demo", "--n-sources", "2", "--outdir", str(tmp_path / "x")]) == 2
    assert "between 3 and 18" in capsys.readouterr().err
    assert main(["demo", "--scene", "messy", "--outdir", str(tmp_path / "x")]) == 2
    assert "invalid choice" in capsys.readouterr().err
    assert main(["demo", "--scene", "realistic", "--cluster-radii", "50", "1",
                 "--outdir", str(tmp_path / "x")]) == 2
    assert "LOW must not exceed HIGH" in capsys.readouterr().err
    assert main([]) == 2
    assert not (tmp_path / "x").exists()


def test_run_reproduces_the_demo(demo_dir, tmp_path):
    out = tmp_path / "run-out"
    assert main(["run", str(demo_dir / "run.toml"), "--outdir", str(out), "--quiet"]) == 0
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    demo = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    run = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    assert list(run["pair_id"]) == list(demo["pair_id"])
    for name in ("id1", "id2", "anomalous", "parity"):
        assert np.array_equal(np.asarray(run[name]), np.asarray(demo[name])), name
    for name in ("x1", "y1", "x2", "y2", "mu_size", "mu_size_err", "mu_flux", "snr"):
        np.testing.assert_allclose(np.asarray(run[name].value if hasattr(run[name], "unit")
                                              else run[name]),
                                   np.asarray(demo[name].value if hasattr(demo[name], "unit")
                                              else demo[name]),
                                   rtol=1e-6, err_msg=name)


def test_the_demo_from_python_gives_the_command_s_report(demo_dir):
    """lensdual.demo and lensdual.pipeline, called from Python without the command line,
    give the demo command's pairs table and report for the same settings."""
    from lensdual.demo import compare_with_truth, render_demo, simulate_demo, truth_paragraph
    from lensdual.pipeline import Analysis, analyse, format_pairs_table, format_report

    system, truth = simulate_demo(n_sources=8, seed=3)
    demo = render_demo(system, truth, seed=3)
    analysis = analyse(demo.images, psf=demo.psf, n_bootstrap=200, seed=3,
                       null_realisations=1000)
    assert isinstance(analysis, Analysis)
    comparison = compare_with_truth(analysis.result, truth, demo.centre)
    report = (demo_dir / "report.txt").read_text()
    assert report.startswith(format_pairs_table(analysis.result) + "\n")
    assert report == format_report(analysis, ["", truth_paragraph(comparison)]) + "\n"
    table = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    assert list(table["pair_id"]) == list(analysis.result["pair_id"])
    for name in ("mu_size", "mu_size_err", "mu_flux", "snr"):
        np.testing.assert_allclose(np.asarray(table[name]), np.asarray(analysis.result[name]),
                                   rtol=1e-12, err_msg=name)


def test_bad_pipeline_settings_fail_before_any_work():
    import lensdual.demo
    import lensdual.pipeline

    with pytest.raises(ValueError, match="estimator must be one of"):
        lensdual.pipeline.analyse({"L1": {}, "L2": {}}, estimator="quad3")
    with pytest.raises(ValueError, match="between 3 and 18"):
        lensdual.demo.simulate_demo(n_sources=2)


def test_run_default_outdir_is_relative_to_the_config(demo_dir, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(demo_dir / "data", copy / "data")
    shutil.copy(demo_dir / "run.toml", copy / "run.toml")
    assert main(["run", str(copy / "run.toml"), "--quiet"]) == 0
    assert (copy / "run-output" / "pairs.ecsv").is_file()


class _StopAtAnalysis(Exception):
    """Raised by :func:`_stop_at_analysis`'s stand-in for ``analyse``."""


def _stop_at_analysis(monkeypatch):
    """Replace the command line's ``analyse`` by one that records its keyword
    arguments and raises `_StopAtAnalysis`; the dict it records into."""
    import lensdual.cli

    seen = {}

    def analyse(*args, **kwargs):
        seen.update(kwargs)
        raise _StopAtAnalysis

    monkeypatch.setattr(lensdual.cli, "analyse", analyse)
    return seen


def test_run_passes_the_source_model_to_the_photometry(demo_dir, tmp_path, monkeypatch):
    """``[analysis] source_model`` and ``snr_definition`` reach the analysis
    (stopped there: the fit itself is tested in tests/test_resolved_photometry.py)."""
    import shutil

    seen = _stop_at_analysis(monkeypatch)
    copy = tmp_path / "copy"
    shutil.copytree(demo_dir / "data", copy / "data")
    text = (demo_dir / "run.toml").read_text()
    assert "[analysis]" in text
    text = text.replace("[analysis]", '[analysis]\nsource_model = "resolved"\n'
                        'snr_definition = "conservative"', 1)
    (copy / "run.toml").write_text(text)
    with pytest.raises(_StopAtAnalysis):
        main(["run", str(copy / "run.toml"), "--quiet"])
    assert seen["source_model"] == "resolved"
    assert seen["snr_definition"] == "conservative"


def _bad_configs(demo_dir):
    """(name, change to the demo's config, expected fragment) of bad configurations."""
    data_dir = demo_dir / "data"

    def change(fn):
        cfg = _absolute_config(demo_dir)
        fn(cfg)
        return cfg

    return [
        ("unknown key", change(lambda c: c["analysis"].update(estimater="quad")), "estimater"),
        ("unknown estimator", change(lambda c: c["analysis"].update(estimator="quadd")),
         "quadd"),
        ("missing image", change(lambda c: c["arcs"]["L1"]["F150W"].update(
            image=str(data_dir / "nope.fits"))), "nope.fits"),
        ("unitless sigma_pos", change(lambda c: c["analysis"].update(sigma_pos="0.01")),
         "sigma_pos"),
        ("wrong unit", change(lambda c: c["analysis"].update(sigma_pos="0.01 kg")), "kg"),
        ("n_bootstrap not int", change(lambda c: c["analysis"].update(n_bootstrap="many")),
         "n_bootstrap"),
        ("missing arc", change(lambda c: c["arcs"].pop("L2")), "L2"),
        ("psf twice", change(lambda c: c["bands"]["F150W"].update(psf_fwhm="0.05 arcsec")),
         "psf_fwhm"),
        ("band missing on an arc", change(lambda c: c["arcs"]["L2"].pop("F200W")), "F200W"),
        ("manual without file", change(lambda c: c.update(pairing={"method": "manual"})),
         "file"),
        ("bad redshifts", change(lambda c: c.update(parametric={"fit": True, "z_lens": 0.4,
                                                                 "z_source": 0.3})),
         "z_source"),
        ("negative threshold", change(lambda c: c["analysis"].update(snr_threshold=-1.0)),
         "snr_threshold"),
    ]


def test_bad_configs_exit_2_and_write_nothing(demo_dir, tmp_path, capsys):
    cases = _bad_configs(demo_dir)
    assert len(cases) >= 8
    for name, cfg, fragment in cases:
        path = _write(tmp_path / f"{name.replace(' ', '_')}.toml", cfg)
        out = tmp_path / f"out_{name.replace(' ', '_')}"
        assert main(["run", str(path), "--outdir", str(out)]) == 2, name
        err = capsys.readouterr().err
        assert fragment in err, (name, err)
        assert "problem" in err, (name, err)
        assert not out.exists(), name
    # a TOML syntax error and a missing config file
    broken = tmp_path / "broken.toml"
    broken.write_text("[analysis\nestimator = 'quad'\n")
    assert main(["run", str(broken), "--outdir", str(tmp_path / "o1")]) == 2
    assert "line 1" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "absent.toml"), "--outdir", str(tmp_path / "o2")]) == 2
    assert "absent.toml" in capsys.readouterr().err
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]


def test_failure_mid_run_leaves_no_output(demo_dir, tmp_path, capsys):
    """Catalogues of 2 sources: the pairing cannot start; exit 1, nothing written."""
    from astropy.coordinates import SkyCoord

    cat = QTable.read(demo_dir / "catalog_L1.ecsv", format="ascii.ecsv")
    small = QTable({"id": cat["id"][:2], "sky": SkyCoord(cat["sky"][:2])})
    small.write(tmp_path / "few.ecsv", format="ascii.ecsv")
    cfg = _absolute_config(demo_dir)
    cfg["catalogs"] = {"L1": str(tmp_path / "few.ecsv"), "L2": str(tmp_path / "few.ecsv")}
    path = _write(tmp_path / "few.toml", cfg)
    out = tmp_path / "out"
    assert main(["run", str(path), "--outdir", str(out), "--quiet"]) == 1
    assert "needs at least 7" in capsys.readouterr().err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]


def test_manual_pairs_from_a_previous_run(demo_dir, tmp_path):
    """The ids of a run's catalogues, given back as manual pairs, give the same pairs."""
    previous = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    QTable({"id1": previous["id1"][:7], "id2": previous["id2"][:7]}).write(
        tmp_path / "pairs.ecsv", format="ascii.ecsv")
    cfg = _absolute_config(demo_dir)
    cfg["pairing"] = {"method": "manual", "file": str(tmp_path / "pairs.ecsv")}
    path = _write(tmp_path / "manual.toml", cfg)
    assert main(["run", str(path), "--outdir", str(tmp_path / "out"), "--quiet"]) == 0
    table = QTable.read(tmp_path / "out" / "pairs.ecsv", format="ascii.ecsv")
    assert len(table) == 7
    assert list(table["id1"]) == list(previous["id1"][:7])
    assert list(table["id2"]) == list(previous["id2"][:7])


def test_command_line_as_a_subprocess(tmp_path):
    """``lensdual`` (the installed script, else ``python -m lensdual``) in a fresh process."""
    script = Path(sys.executable).with_name("lensdual")
    command = [str(script)] if script.is_file() else [sys.executable, "-m", "lensdual"]
    env = dict(os.environ, MPLBACKEND="agg")
    done = subprocess.run(command + ["demo", "--outdir", str(tmp_path / "sub"), "--quiet",
                                     "--n-sources", "8", "--n-bootstrap", "100"],
                          capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "sub" / "pairs.ecsv").is_file()
    done = subprocess.run(command + ["run", str(tmp_path / "missing.toml")],
                          capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 2
    assert "missing.toml" in done.stderr


LENSTOOL_NFW = """\
runmode
    reference     3 {ra:.7f} {dec:.7f}
    end
potentiel O1
    profil        12
    x_centre      0.0
    y_centre      0.0
    ellipticite   0.05
    angle_pos     0.0
    concentration 9.6
    m200          5e14
    z_lens        0.39
    end
""" + COSMOLOGY + "fini\n"


def test_run_with_a_lenstool_model(demo_dir, tmp_path):
    """[parametric] lenstool: the model's ratios at the pairs' sky positions."""
    import astropy.units as u

    from lensdual.parametric import read_lenstool
    from lensdual.simulation.mock import DEFAULT_SKY_CENTER

    par = tmp_path / "best.par"
    par.write_text(LENSTOOL_NFW.format(ra=DEFAULT_SKY_CENTER.ra.deg,
                                       dec=DEFAULT_SKY_CENTER.dec.deg))
    cfg = _absolute_config(demo_dir)
    cfg["parametric"] = {"lenstool": str(par), "z_lens": 0.39, "z_source": 2.2}
    path = _write(tmp_path / "lenstool.toml", cfg)
    out = tmp_path / "out"
    assert main(["run", str(path), "--outdir", str(out), "--quiet"]) == 0
    assert (out / "parametric.png").is_file()
    table = QTable.read(out / "parametric.ecsv", format="ascii.ecsv")
    pairs = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    assert "Lenstool model best.par" in (out / "report.txt").read_text()
    # independent: the model's magnifications at the pairs' positions in its frame
    model = read_lenstool(par)
    system = model.lens_system(z_source=2.2)
    mu1 = system.magnification(model.to_model_frame(pairs["sky1"]))
    mu2 = system.magnification(model.to_model_frame(pairs["sky2"]))
    column = "mu_model" if "mu_model" in table.colnames else "mu_lenstool"
    np.testing.assert_allclose(np.asarray(table[column]), np.abs(mu1 / mu2), rtol=1e-8)
    # the NFW stands in for the analogue's main halo: same fold, similar ratios
    ratio = np.asarray(table[column]) / np.asarray(pairs["mu_size"])
    assert np.all((ratio > 0.5) & (ratio < 2.0))
    assert u.Quantity(model.to_model_frame(pairs["sky1"])).unit == u.arcsec


def test_demo_parametric(tmp_path, monkeypatch):
    """--parametric adds the fit (made cheap here) and its comparison to the outputs."""
    import lensdual.cli as cli

    monkeypatch.setattr(cli, "_DEMO_FIT", {"sigma_pos": 0.01, "n_starts": 1, "max_nfev": 60,
                                          "fix_centre": True})
    out = tmp_path / "par"
    assert main(["demo", "--outdir", str(out), "--parametric", "--write-config", "--quiet",
                 "--n-sources", "7", "--n-bootstrap", "50"]) == 0
    table = QTable.read(out / "parametric.ecsv", format="ascii.ecsv")
    assert len(table) == 7
    for name in ("mu_flux", "mu_size", "mu_model", "snr_model", "anomalous_model"):
        assert name in table.colnames
    assert table.meta["parametric"]["fit_model"] == ["NFW_ELLIPSE_CSE", "SHEAR"]
    assert (out / "parametric.png").is_file()
    assert "parametric lenstronomy fit" in (out / "report.txt").read_text()
    cfg = tomllib.loads((out / "run.toml").read_text())
    assert cfg["parametric"]["fit"] is True
    assert cfg["parametric"]["sigma_pos"] == "0.01 arcsec"
    assert cfg["parametric"]["fix_centre"] is True
    # the written config runs, with the same fit settings read from the file
    from lensdual.config import load_config

    spec = load_config(out / "run.toml").parametric
    assert spec.fix_centre and spec.fit and spec.centre is not None


def test_demo_table_matches_the_stored_reference(demo_dir):
    """The pairs table of the FAST demo equals the stored reference
    tests/data/demo_fast_pairs.ecsv: every float column to a relative 1e-6, so
    a refactor cannot move the demo's results. Regenerate the reference only
    for an intended change of results (and say so in CHANGES.rst)."""
    ref = QTable.read(Path(__file__).parent / "data" / "demo_fast_pairs.ecsv",
                      format="ascii.ecsv")
    table = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    assert len(table) == len(ref)
    for name in ref.colnames:
        got, want = table[name], ref[name]
        if want.dtype.kind in "fc":
            np.testing.assert_allclose(np.asarray(got.value if hasattr(got, "unit") else got,
                                                  dtype=float),
                                       np.asarray(want.value if hasattr(want, "unit") else want,
                                                  dtype=float),
                                       rtol=1e-6, atol=1e-12, err_msg=name)
            if getattr(want, "unit", None) is not None:
                assert got.unit == want.unit, name
        else:
            assert list(got) == list(want), name


@pytest.mark.parametrize("option, key, value, default", [
    ("--snr-definition", "snr_definition", "log", "auto"),
    ("--source-model", "source_model", "resolved", "point"),
])
def test_demo_passes_analysis_options(tmp_path, monkeypatch, option, key, value, default):
    """``lensdual demo --snr-definition log`` and ``--source-model
    resolved`` reach the analysis, and the run configuration the demo writes
    keeps them (its default is left out; stopped at the analysis; that
    ``lensdual run`` reads the keys is tested above); an unknown value is a
    usage error."""
    from lensdual._outputs import write_run_inputs

    seen = _stop_at_analysis(monkeypatch)
    with pytest.raises(_StopAtAnalysis):
        main(["demo", option, value, "--n-sources", "6", "--quiet",
              "--null-realisations", "0", "--outdir", str(tmp_path / "out")])
    assert seen[key] == value
    kw = dict(estimator="adaptive", n_bootstrap=200, snr_threshold=3.0, seed=0, centre=None)
    config, _ = write_run_inputs({}, tmp_path, **{key: value}, **kw)
    assert config["analysis"][key] == value
    config, _ = write_run_inputs({}, tmp_path, **{key: default}, **kw)
    assert key not in config["analysis"]
    assert main(["demo", option, "neither", "--outdir", str(tmp_path / "bad")]) == 2
